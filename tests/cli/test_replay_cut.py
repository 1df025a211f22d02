"""``warden replay`` on a record cut off mid-write (a run killed with SIGKILL while writing):
the incomplete last line is dropped, named on stderr, and everything before it replays and is
compared (exit 3: the record is incomplete); damage anywhere else is still invalid input."""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from assurance.fallback import Owner
from kernel.cli import main
from kernel.core.effects import Setpoint
from kernel.replay import same_bits

_Capture = pytest.CaptureFixture[str]


@pytest.fixture
def run_copy(lockstep_run: Path, tmp_path: Path) -> Path:
    """A copy of a real run's directory (``warden run --clock virtual --cycles 1``, the
    session's shared record, tests/conftest.py)."""
    copy = tmp_path / "run"
    shutil.copytree(lockstep_run, copy)
    return copy


def _cut(path: Path, fraction: float) -> int:
    """Cut the file inside a line (never on a line boundary); the number of that line."""
    data = path.read_bytes()
    at = int(len(data) * fraction)
    while data[at - 1:at] == b"\n" or data[at:at + 1] == b"\n":
        at += 1
    path.write_bytes(data[:at])
    return data[:at].count(b"\n") + 1


def test_a_complete_run_replays_identically(run_copy: Path, capsys: _Capture) -> None:
    assert main(["replay", str(run_copy / "journal.jsonl")]) == 0
    assert "identical: " in capsys.readouterr().err


def test_a_journal_cut_mid_line_replays_up_to_the_cut(run_copy: Path, capsys: _Capture) -> None:
    journal = run_copy / "journal.jsonl"
    line = _cut(journal, 0.5)
    assert main(["replay", str(journal)]) == 3
    out, err = capsys.readouterr()
    assert f"{journal}: line {line} is incomplete" in err
    assert f"replaying lines 1 to {line - 1}" in err
    assert "identical as far as the record goes" in err and "record is incomplete" in err
    replayed = out.encode()
    recorded = (run_copy / "decisions.jsonl").read_bytes()
    assert replayed and recorded.startswith(replayed)  # the prefix, byte for byte
    assert len(replayed) < len(recorded) // 2 + len(recorded) // 4


def test_a_decision_log_cut_mid_line_is_compared_up_to_the_cut(run_copy: Path,
                                                               capsys: _Capture) -> None:
    decisions = run_copy / "decisions.jsonl"
    line = _cut(decisions, 0.7)
    assert main(["replay", str(run_copy / "journal.jsonl")]) == 3
    err = capsys.readouterr().err
    assert f"{decisions}: line {line} is incomplete" in err
    assert f"the {line - 1} decision lines both files hold" in err


def test_a_cut_journal_that_differs_before_the_cut_is_a_difference(run_copy: Path,
                                                                    capsys: _Capture) -> None:
    _cut(run_copy / "journal.jsonl", 0.5)
    decisions = run_copy / "decisions.jsonl"
    lines = decisions.read_bytes().splitlines(keepends=True)
    lines[10] = lines[10].replace(b'"t":', b'"t": ', 1)
    decisions.write_bytes(b"".join(lines))
    assert main(["replay", str(run_copy / "journal.jsonl")]) == 1
    assert "first difference in decisions.jsonl line 11" in capsys.readouterr().err


def test_a_broken_line_before_the_last_is_invalid_input(run_copy: Path,
                                                        capsys: _Capture) -> None:
    journal = run_copy / "journal.jsonl"
    lines = journal.read_bytes().splitlines(keepends=True)
    lines[5] = lines[5][: len(lines[5]) // 2] + b"\n"  # damage the cut cannot produce
    journal.write_bytes(b"".join(lines[:100]) + lines[100][:20])
    assert main(["replay", str(journal)]) == 2
    assert "line 6 is not valid JSON" in capsys.readouterr().err


def test_a_cut_last_line_that_ends_in_its_newline_is_damage(run_copy: Path,
                                                            capsys: _Capture) -> None:
    journal = run_copy / "journal.jsonl"
    lines = journal.read_bytes().splitlines(keepends=True)
    journal.write_bytes(b"".join(lines[:100]) + lines[100][:20] + b"\n")
    assert main(["replay", str(journal)]) == 2
    assert "line 101 is not valid JSON" in capsys.readouterr().err


def test_a_line_cut_inside_a_character_is_a_cut(run_copy: Path, capsys: _Capture) -> None:
    journal = run_copy / "journal.jsonl"
    lines = journal.read_bytes().splitlines(keepends=True)
    cut_inside_e_acute = '{"t": 200, "kind": "observation", "observation_id": "é'.encode()[:-1]
    journal.write_bytes(b"".join(lines[:100]) + cut_inside_e_acute)
    assert main(["replay", str(journal)]) == 3
    assert f"{journal}: line 101 is incomplete" in capsys.readouterr().err


def test_a_decision_log_that_stops_at_a_line_boundary_is_incomplete(run_copy: Path,
                                                                    capsys: _Capture) -> None:
    """A run killed between writing a batch to its journal and to its decision log."""
    decisions = run_copy / "decisions.jsonl"
    lines = decisions.read_bytes().splitlines(keepends=True)
    decisions.write_bytes(b"".join(lines[:-40]))
    assert main(["replay", str(run_copy / "journal.jsonl")]) == 3
    err = capsys.readouterr().err
    assert f"ends after {len(lines) - 40} of the {len(lines)} lines replayed" in err


def test_a_decision_log_longer_than_its_whole_journal_is_a_difference(run_copy: Path,
                                                                      capsys: _Capture) -> None:
    decisions = run_copy / "decisions.jsonl"
    lines = decisions.read_bytes().splitlines(keepends=True)
    decisions.write_bytes(b"".join(lines + lines[-1:]))
    assert main(["replay", str(run_copy / "journal.jsonl")]) == 1
    assert f"{len(lines) + 1} lines recorded, {len(lines)} replayed" in capsys.readouterr().err


def _altered_setpoint(journal: Path, alter: Callable[[float], float]) -> int:
    """Rewrite the first policy setpoint's first joint in the journal; its command number."""
    lines = journal.read_bytes().splitlines(keepends=True)
    commands = 0
    for at, raw in enumerate(lines):
        record = json.loads(raw)
        if record.get("kind") != "command" or record.get("origin", "core") != "core":
            continue
        commands += 1
        effect = record["effect"]
        if effect.get("effect") == "setpoint" and effect.get("chunk_id"):
            effect["q"][0] = alter(effect["q"][0])
            lines[at] = json.dumps(record).encode() + b"\n"
            journal.write_bytes(b"".join(lines))
            return commands
    raise AssertionError("the run wrote no policy setpoint")


@pytest.mark.parametrize("alter", [lambda q: math.nextafter(q, math.inf),
                                   lambda q: math.nextafter(q, -math.inf)],
                         ids=["one ulp up", "one ulp down"])
def test_a_command_one_ulp_off_is_the_first_difference(run_copy: Path, capsys: _Capture,
                                                       alter: Callable[[float], float]) -> None:
    number = _altered_setpoint(run_copy / "journal.jsonl", alter)
    assert main(["replay", str(run_copy / "journal.jsonl")]) == 1
    err = capsys.readouterr().err
    assert "first difference at " in err and f"(command {number})" in err
    assert "the journal records" in err and "the core decided" in err


def test_commands_compare_to_the_bit() -> None:
    """-0.0 == 0.0 and NaN != NaN in Python; neither holds for the journal's comparison."""
    def setpoint(q0: float) -> Setpoint:
        return Setpoint(q=(q0, 0.5), gripper=None, owner=Owner.POLICY, chunk_id="c", index=0)

    assert same_bits(setpoint(0.0), setpoint(0.0))
    assert not same_bits(setpoint(0.0), setpoint(-0.0))
    assert same_bits(setpoint(math.nan), setpoint(math.nan))
    assert not same_bits(setpoint(0.5), setpoint(math.nextafter(0.5, 1.0)))


def _without_last_commands(journal: Path, count: int) -> None:
    """Drop the last ``count`` command records (a run ended before writing them)."""
    lines = journal.read_bytes().splitlines(keepends=True)
    commands = [at for at, raw in enumerate(lines) if b'"kind":"command"' in raw]
    dropped = set(commands[-count:])
    journal.write_bytes(b"".join(raw for at, raw in enumerate(lines) if at not in dropped))


def test_one_missing_trailing_command_is_a_run_ended_mid_tick(run_copy: Path,
                                                              capsys: _Capture) -> None:
    _without_last_commands(run_copy / "journal.jsonl", 1)
    assert main(["replay", str(run_copy / "journal.jsonl")]) == 0
    assert "identical: " in capsys.readouterr().err


def test_two_missing_trailing_commands_are_a_difference(run_copy: Path,
                                                        capsys: _Capture) -> None:
    _without_last_commands(run_copy / "journal.jsonl", 2)
    assert main(["replay", str(run_copy / "journal.jsonl")]) == 1
    assert "the journal records no command for it" in capsys.readouterr().err
