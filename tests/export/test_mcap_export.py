"""``warden export RUN --mcap``: a recorded run (the shared lockstep run of the simulated cell)
written with Foxglove's SDK and read back with the independent ``mcap`` reader, message for
message against the journal and the decision log."""

from __future__ import annotations

import json
import shutil
from collections import Counter
from pathlib import Path

import pytest
from mcap.reader import make_reader

from kernel.cli import main


def _read(path: Path) -> tuple[Counter[str], dict[str, tuple[str, str]], dict[str, list[dict]]]:
    counts: Counter[str] = Counter()
    schemas: dict[str, tuple[str, str]] = {}
    bodies: dict[str, list[dict]] = {}
    with open(path, "rb") as file:
        for schema, channel, message in make_reader(file).iter_messages():
            counts[channel.topic] += 1
            schemas[channel.topic] = (schema.name if schema else "", channel.message_encoding)
            if channel.message_encoding == "json":
                bodies.setdefault(channel.topic, []).append(json.loads(message.data))
    return counts, schemas, bodies


def _lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_every_record_of_a_run_becomes_its_messages(lockstep_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run.mcap"
    assert main(["export", str(lockstep_run), "--mcap", "--out", str(out)]) == 0
    counts, schemas, bodies = _read(out)
    journal = Counter(line.get("kind") for line in _lines(lockstep_run / "journal.jsonl"))
    decisions = Counter(line["kind"] for line in _lines(lockstep_run / "decisions.jsonl"))
    commands = [line for line in _lines(lockstep_run / "journal.jsonl")
                if line.get("kind") == "command"]
    targets = sum(1 for line in commands if "q" in line["effect"])
    assert counts["/joint_states"] == counts["/tcp"] == journal["state"] > 1000
    assert counts["/commands"] == journal["command"]
    assert counts["/joint_commands"] == counts["/tcp_target"] == targets > 0
    assert counts["/ticks"] == decisions["tick"]
    assert counts["/decisions"] == decisions["chunk"] > 0
    assert counts["/transitions"] == decisions["transition"] > 0
    assert counts["/observations"] == journal["observation"]
    assert counts["/chunks_in"] == journal["chunk"]
    assert counts["/summary"] == 1
    assert schemas["/joint_states"] == ("foxglove.JointStates", "protobuf")
    assert schemas["/tcp"] == ("foxglove.PoseInFrame", "protobuf")
    assert schemas["/decisions"] == ("warden.decisions", "json")
    first = bodies["/decisions"][0]
    assert first == next(line for line in _lines(lockstep_run / "decisions.jsonl")
                         if line["kind"] == "chunk")
    assert bodies["/summary"][0]["cycles"]["verified"] == 1


def test_a_record_cut_off_mid_line_exports_what_it_holds(lockstep_run: Path,
                                                         tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(lockstep_run, run)
    for name in ("journal.jsonl", "decisions.jsonl"):
        data = (run / name).read_bytes()
        (run / name).write_bytes(data[:-40])  # the last line cut off as it was written
    assert main(["export", str(run), "--mcap"]) == 0
    counts, _, _ = _read(run / "run.mcap")
    assert counts["/joint_states"] > 1000


@pytest.mark.parametrize(("setup", "needle"), [
    ("empty", "not a run directory (no journal.jsonl)"),
    ("exists", "exists already"),
    ("garbage", "journal.jsonl"),
])
def test_bad_input_exits_2_naming_it(lockstep_run: Path, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str], setup: str,
                                     needle: str) -> None:
    run = tmp_path / "run"
    if setup == "empty":
        run.mkdir()
    else:
        shutil.copytree(lockstep_run, run)
    if setup == "exists":
        (run / "run.mcap").write_bytes(b"mine")
    if setup == "garbage":
        (run / "journal.jsonl").write_text('{"format": "warden-journal/1"}\n{"t": "x"}\n')
    assert main(["export", str(run), "--mcap"]) == 2
    assert needle in capsys.readouterr().err
    if setup == "exists":
        assert (run / "run.mcap").read_bytes() == b"mine"
