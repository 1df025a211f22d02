"""``warden replay`` on files that are broken or absurd: exit 2, one line naming the file and
the key, no traceback, nothing printed on stdout.

Each case is one a new user hit: a file that is not UTF-8, nesting or an integer no parser
survives, a limit or threshold far outside what any arm can do, a scenario too long to replay,
and (fail closed) an unknown key or a missing limit. Journals (a header line, then one event a
line) are read by the same code and checked the same way.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from kernel.cli import main
from kernel.manifest import load_manifest

ROOT = Path(__file__).resolve().parents[2]
SEED = ROOT / "manifests" / "scenarios" / "seed_stale_chunk.json"
HUGE = "9" * 5000
"""An integer literal of 5000 digits (Python refuses to print one: it is spliced into text)."""


def _seed() -> dict[str, Any]:
    return json.loads(SEED.read_text())


def _replay(path: Path, capsys: pytest.CaptureFixture[str]) -> str:
    code = main(["replay", str(path)])
    captured = capsys.readouterr()
    assert code == 2, captured.err
    assert captured.out == ""
    assert "Traceback" not in captured.err
    assert captured.err.startswith(f"warden: invalid input: {path}: ")
    assert captured.err.count("\n") == 1
    return captured.err


def _changed(change: Callable[[dict[str, Any]], Any]) -> dict[str, Any]:
    doc = _seed()
    change(doc)
    return doc


def _set(section: str, **values: Any) -> Callable[[dict[str, Any]], Any]:
    return lambda doc: doc[section].update(values)


def _phase(name: str, **values: Any) -> Callable[[dict[str, Any]], Any]:
    return lambda doc: doc["phases"].setdefault(name, {}).update(values)


def _event(**event: Any) -> Callable[[dict[str, Any]], Any]:
    return lambda doc: doc["events"].append({"t": 400, **event})


ABSURD = [
    ("velocity 1e9", _set("robot", velocity_limits=[1e9] * 6), "robot.velocity_limits[0]"),
    ("one velocity 1e9", _set("robot", velocity_limits=1e9), "robot.velocity_limits"),
    ("acceleration 1e12", _set("robot", acceleration_limits=[40.0] * 5 + [1e12]),
     "robot.acceleration_limits[5]"),
    ("position ±1e12", _set("robot", position_limits=1e12), "robot.position_limits"),
    ("position pair 1e12", _set("robot", position_limits=[[-1e12, 1e12]] * 6),
     "robot.position_limits[0][0]"),
    ("divergence 1e9", _phase("CONTACT", max_divergence=1e9), "phases.CONTACT.max_divergence"),
    ("projection 100", _phase("FREE_SPACE", max_projection=100.0),
     "phases.FREE_SPACE.max_projection"),
    ("state outside limits", _set("session", state=[0.0, 0.0, 50.0, 0.0, 0.0, 0.0]),
     "session.state[2]"),
    ("dof 3e8", _set("robot", dof=3e8, position_limits=1.0, velocity_limits=1.0,
                     acceleration_limits=1.0), "robot.dof"),
    ("until 1e12", lambda doc: doc.update(until=1e12), "until"),
    ("last event at 1e12", lambda doc: (doc.pop("until"), _event(kind="ood", score=0.1,
                                                                  t=1e12)(doc)),
     "until: not set, and its default, the time of the last event (1e+12 ms)"),
    ("too many ticks", lambda doc: (doc.update(until=3_000_000),
                                    doc["timing"].update(control_period_ms=0.05)), "until"),
    ("period 1e12", _set("timing", control_period_ms=1e12), "timing.control_period_ms"),
    ("uncertainty an hour", _set("timing", clock_uncertainty_ms=3.6e6),
     "timing.clock_uncertainty_ms"),
    ("watchdog below a period", _set("timing", state_timeout_ms=0.5), "timing.state_timeout_ms"),
    ("degrade after 1e9", _set("timing", degrade_after=10**9), "timing.degrade_after"),
    ("watermark a day", _set("timing", high_watermark_ms=8.64e7), "timing.high_watermark_ms"),
    ("action age a day", _phase("CONTACT", max_action_age_ms=8.64e7),
     "phases.CONTACT.max_action_age_ms"),
    ("force band 1e9", _phase("CONTACT", force_band=1e9), "phases.CONTACT.force_band"),
    ("planner speed 1e9", lambda doc: doc.update(motion={"planner_velocity": 1e9}),
     "motion.planner_velocity"),
    ("workspace 1 km", _set("robot", workspace={"lower": [-1e3, 0, 0], "upper": [1, 1, 1]}),
     "robot.workspace.lower[0]"),
    ("queue epoch 2**40", _set("session", queue_epoch=2**40), "session.queue_epoch"),
    ("protocol 0", _set("session", protocol=[0, 1]), "session.protocol"),
    ("clock offset 1e13 ms", _event(kind="clock_sync", domain="server", offset_ms=1e13,
                                    round_trip_ms=1), "events[25] (clock_sync).offset_ms"),
    ("event time 1e13 ms", _event(kind="ood", score=0.1, t=1e13), "events[25] (ood).t"),
    ("gripper threshold 1e9", _set("robot", gripper_event_threshold=1e9),
     "robot.gripper_event_threshold"),
]

FAIL_CLOSED = [
    ("unknown robot key", _set("robot", max_velocity=1.0), "robot.max_velocity: unknown key"),
    ("unknown timing key", _set("timing", control_period=2), "timing.control_period: unknown"),
    ("unknown phase", lambda doc: doc["phases"].update(LUNCH={}), "phases.LUNCH"),
    ("unknown phase-card key", _phase("CONTACT", max_divergance=0.1),
     "phases.CONTACT.max_divergance: unknown key"),
    ("unknown session key", _set("session", queue_epok=1), "session.queue_epok: unknown key"),
    ("unknown motion key", lambda doc: doc.update(motion={"planner_speed": 1.0}),
     "motion.planner_speed: unknown key"),
    ("no position limit", lambda doc: doc["robot"].pop("position_limits"),
     "robot: missing required key 'position_limits'"),
    ("no velocity limit", lambda doc: doc["robot"].pop("velocity_limits"),
     "robot: missing required key 'velocity_limits'"),
    ("no acceleration limit", lambda doc: doc["robot"].pop("acceleration_limits"),
     "robot: missing required key 'acceleration_limits'"),
]


@pytest.mark.parametrize(("change", "needle"), [case[1:] for case in ABSURD + FAIL_CLOSED],
                         ids=[case[0] for case in ABSURD + FAIL_CLOSED])
def test_an_absurd_or_unknown_value_exits_2_naming_the_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], change: Callable[[dict[str, Any]], Any],
    needle: str,
) -> None:
    path = tmp_path / "scenario.json"
    path.write_text(json.dumps(_changed(change)))
    assert needle in _replay(path, capsys)


def test_the_bounds_keep_every_shipped_scenario(capsys: pytest.CaptureFixture[str]) -> None:
    for path in sorted((ROOT / "manifests" / "scenarios").glob("*.json")):
        assert main(["replay", str(path)]) == 0, capsys.readouterr().err
        capsys.readouterr()


def _text_cases() -> list[tuple[str, bytes, str]]:
    seed = SEED.read_bytes()
    return [
        ("not UTF-8", seed.replace(b'"seed_stale_chunk"', b'"seed\xff"', 1),
         "line 3 column 16: not UTF-8 text (byte 0xff)"),
        ("latin-1", "{\"name\": \"Stra\u00dfe\"}".encode("latin-1"), "not UTF-8 text"),
        ("nested 100000 deep", b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
        ("nested objects", b'{"a":' * 50_000 + b"1" + b"}" * 50_000, "nested too deeply"),
        ("nested 40 deep in a key", seed.replace(b'"dof": 6', b'"dof": ' + b"[" * 40 + b"6"
                                                 + b"]" * 40, 1), "robot.dof[0]"),
        ("5000-digit dof", seed.replace(b'"dof": 6', b'"dof": ' + HUGE.encode(), 1),
         "robot.dof: an integer of 5000 digits"),
        ("400-digit state", seed.replace(b'"state": [0.0', b'"state": [' + b"9" * 400, 1),
         "session.state[0]: an integer of 400 digits"),
        ("5000-digit event time", seed.replace(b'"t": 0,', b'"t": ' + HUGE.encode() + b",", 1),
         "events[0].t: an integer of 5000 digits"),
        ("lone surrogate", seed.replace(b'"peg_insert"', b'"\\ud800"', 1),
         "session.skill: the value is not valid Unicode text"),
        ("float literal out of range", seed.replace(b'"dof": 6', b'"dof": 1e999', 1),
         "robot.dof: must be an integer, got inf"),
    ]


@pytest.mark.parametrize(("raw", "needle"), [c[1:] for c in _text_cases()],
                         ids=[c[0] for c in _text_cases()])
def test_a_file_no_parser_survives_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                           raw: bytes, needle: str) -> None:
    path = tmp_path / "scenario.json"
    path.write_bytes(raw)
    assert needle in _replay(path, capsys)


# -- journals -----------------------------------------------------------------------------------


def _journal_lines() -> list[str]:
    """A small hand-made journal: the shipped manifest's sections as the header, the handshake
    and a few ticks (what a live run records, shortened)."""
    sections = load_manifest(ROOT / "manifests" / "sim-ur5e.toml").sections.document()
    head = {"format": "warden-journal/1", "name": "handmade", **sections}
    q = sections["session"]["state"]
    events = [{"t": 0, "kind": "state", "q": q}]
    events += [{"t": 2 * k, "kind": "tick"} for k in range(5)]
    return [json.dumps(head), *(json.dumps(e) for e in events)]


def test_the_handmade_journal_replays(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "journal.jsonl"
    path.write_text("\n".join(_journal_lines()))
    assert main(["replay", str(path)]) == 0
    assert "identical" in capsys.readouterr().err


def _journal_cases() -> list[tuple[str, Callable[[list[str]], list[str]], str]]:
    def header(change: Callable[[dict[str, Any]], Any]) -> Callable[[list[str]], list[str]]:
        def apply(lines: list[str]) -> list[str]:
            head = json.loads(lines[0])
            change(head)
            return [json.dumps(head), *lines[1:]]
        return apply

    def line(text: str) -> Callable[[list[str]], list[str]]:
        return lambda lines: [*lines, text]

    return [
        ("header velocity 1e9", header(_set("robot", velocity_limits=1e9)),
         "robot.velocity_limits"),
        ("header state outside", header(_set("session", state=[9.0] * 6)), "session.state[0]"),
        ("header unknown timing key", header(_set("timing", period_ms=2)),
         "timing.period_ms: unknown key"),
        ("header dof 3e8", header(_set("robot", dof=300_000_000)), "robot.dof"),
        ("line not UTF-8", lambda lines: [*lines, '{"t": 12, "kind": "tick"}\udcff'],
         "not UTF-8 text (byte 0xff)"),
        ("line nested", line("[" * 100_000 + "]" * 100_000), "line 8: nested too deeply"),
        ("line 5000 digits", line('{"t": ' + HUGE + ', "kind": "tick"}'),
         "events[6].t: an integer of 5000 digits"),
        ("clock offset 1e20 ns", line('{"t": 12, "kind": "clock_sync", "domain": "server", '
                                      '"offset_ns": 100000000000000000000, "round_trip_ns": 1}'),
         "events[6]"),
        ("clock offset 5e12 ms", line('{"t": 12, "kind": "clock_sync", "domain": "server", '
                                      '"offset_ms": 5e12, "round_trip_ms": 1}'),
         "events[6] (clock_sync).offset_ms: must be at most 4e+12"),
    ]


@pytest.mark.parametrize(("change", "needle"), [c[1:] for c in _journal_cases()],
                         ids=[c[0] for c in _journal_cases()])
def test_a_bad_journal_exits_2_naming_the_line_or_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], change: Callable[[list[str]], list[str]],
    needle: str,
) -> None:
    path = tmp_path / "journal.jsonl"
    text = "\n".join(change(_journal_lines()))
    path.write_bytes(text.encode("utf-8", errors="surrogateescape"))
    assert needle in _replay(path, capsys)


def test_a_damaged_decision_log_beside_a_journal_is_a_difference(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A journal replays against the decisions.jsonl beside it: bytes that are not UTF-8 there
    are a difference to report (exit 1), not a crash."""
    path = tmp_path / "journal.jsonl"
    path.write_text("\n".join(_journal_lines()))
    assert main(["replay", str(path), "--out", str(tmp_path / "decisions.jsonl")]) == 0
    capsys.readouterr()
    decisions = tmp_path / "decisions.jsonl"
    decisions.write_bytes(decisions.read_bytes().replace(b'"kind"', b'"k\xffnd"', 1))
    assert main(["replay", str(path)]) == 1
    err = capsys.readouterr().err
    assert "first difference in decisions.jsonl line 1" in err and "Traceback" not in err
