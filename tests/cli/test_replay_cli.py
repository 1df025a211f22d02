"""``warden replay``: exit codes, output, and clear errors for invalid files (never a traceback)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import msgspec
import pytest

from kernel.cli import main
from kernel.core.lines import MotionDecision, MotionLine, MotionRequest, encode
from kernel.timeline import render

ROOT = Path(__file__).resolve().parents[2]
SEED = ROOT / "manifests" / "scenarios" / "seed_stale_chunk.json"


def _seed() -> dict:
    return json.loads(SEED.read_text())


def _write(tmp_path: Path, doc: object, name: str = "bad.json") -> Path:
    path = tmp_path / name
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


def test_replay_prints_json_lines_and_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(SEED)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines and all(json.loads(line)["kind"] for line in lines)


def test_out_file_equals_stdout(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "log.jsonl"
    assert main(["replay", str(SEED), "--out", str(out)]) == 0
    assert out.read_text() == capsys.readouterr().out


def test_pretty_timeline_names_the_refusals(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(SEED), "--pretty"]) == 0
    text = capsys.readouterr().out
    assert "C41: REJECTED (PHASE_MISMATCH + STATE_DIVERGED)" in text
    assert "C41: IGNORED (DUPLICATE + OLD_QUEUE_EPOCH)" in text


MOTION_LINES = (
    MotionLine(t=120, request=MotionRequest.MOVE, decision=MotionDecision.PLANNED, move_id=3,
               duration_ms=1840.5),
    MotionLine(t=122, request=MotionRequest.MOVE, decision=MotionDecision.REFUSED, move_id=4,
               detail="target is not finite or not inside the position limits"),
    MotionLine(t=130, request=MotionRequest.GRIPPER, decision=MotionDecision.SET, opening=0.085),
    MotionLine(t=140, request=MotionRequest.INSERT, decision=MotionDecision.STARTED),
)


def test_pretty_timeline_renders_motion_lines_readably() -> None:
    """A run's motion lines (planner moves, the gripper, the contact owner's descent), decoded
    from JSON as ``warden replay --pretty`` decodes them, read like every other kind: no raw
    dict."""
    decoded = [msgspec.json.decode(encode(line)) for line in MOTION_LINES]
    text = list(render(decoded))
    assert [line.split("▶ ", 1)[1] for line in text] == [
        "motion move #3 PLANNED, 1840.5 ms",
        "motion move #4 REFUSED (target is not finite or not inside the position limits)",
        "motion gripper SET, opening 0.0850 m",
        "motion insert STARTED",
    ]
    assert not any("{" in line for line in text)


def test_check_passes_and_fails(tmp_path: Path) -> None:
    assert main(["replay", str(SEED), "--check"]) == 0
    doc = _seed()
    doc["expect"] = [{"kind": "chunk", "chunk_id": "C41", "decision": "accepted"}]
    assert main(["replay", str(_write(tmp_path, doc)), "--check"]) == 1


def test_entry_point_runs_as_a_process() -> None:
    done = subprocess.run([sys.executable, "-m", "kernel.cli", "replay", str(SEED)],
                          capture_output=True, text=True, check=False)
    assert done.returncode == 0
    assert '"chunk_id":"C41"' in done.stdout


CARTESIAN = {"action_frame": "base_delta", "action_units": "m", "action_dim": 3}


def _mutations() -> list[tuple[str, object, str]]:
    """(case, document or mutator, text the error must contain)."""
    def mutate(fn):
        doc = _seed()
        fn(doc)
        return doc

    return [
        ("not json", "{ this is not json", "not valid JSON"),
        ("top level list", [1, 2], "top level must be a JSON object"),
        ("wrong format", mutate(lambda d: d.update(format="warden-scenario/9")), "format"),
        ("missing robot", mutate(lambda d: d.pop("robot")), "'robot'"),
        ("dof not int", mutate(lambda d: d["robot"].update(dof="six")), "robot.dof"),
        ("negative velocity", mutate(lambda d: d["robot"].update(velocity_limits=[-1] * 6)),
         "robot.velocity_limits"),
        ("bad limits length", mutate(lambda d: d["robot"].update(position_limits=[[0, 1]] * 3)),
         "robot.position_limits"),
        ("unknown phase", mutate(lambda d: d["phases"].update(LUNCH={})), "phases.LUNCH"),
        ("phase key wrong type", mutate(lambda d: d["phases"]["CONTACT"].update(trim="yes")),
         "phases.CONTACT.trim"),
        ("period zero", mutate(lambda d: d["timing"].update(control_period_ms=0)),
         "timing.control_period_ms"),
        ("nan period", mutate(lambda d: d["timing"].update(control_period_ms=float("nan"))),
         "timing.control_period_ms"),
        ("session phase unknown", mutate(lambda d: d["session"].update(phase="NAP")),
         "session.phase"),
        ("session state wrong size", mutate(lambda d: d["session"].update(state=[0.0] * 4)),
         "session.state"),
        ("events not a list", mutate(lambda d: d.update(events={})), "events"),
        ("event without t", mutate(lambda d: d["events"][0].pop("t")), "events[0]"),
        ("time backwards", mutate(lambda d: d["events"].insert(5, dict(d["events"][0], t=999))),
         "earlier than the event before"),
        ("unknown kind", mutate(lambda d: d["events"].append({"t": 400, "kind": "teleport"})),
         "unknown event kind 'teleport'"),
        ("state wrong dimension", mutate(
            lambda d: d["events"].append({"t": 400, "kind": "state", "q": [0.0] * 5})), "q"),
        ("unknown operator action", mutate(
            lambda d: d["events"].append({"t": 400, "kind": "operator", "action": "dance"})),
         "action"),
        ("unknown link status", mutate(
            lambda d: d["events"].append({"t": 400, "kind": "link", "status": "sideways"})),
         "status"),
        ("phase event unknown target", mutate(
            lambda d: d["events"].append({"t": 400, "kind": "phase", "to": "NAP"})), "to"),
        ("handshake without offer", mutate(
            lambda d: d["events"].append({"t": 400, "kind": "handshake"})), "offer"),
        ("negative until", mutate(lambda d: d.update(until=-5)), "until"),
        ("huge until", mutate(lambda d: d.update(until=1e303)), "until"),
        ("huge event time", mutate(lambda d: d["events"][0].update(t=1e303)), "events[0]"),
        ("huge action age", mutate(
            lambda d: d["phases"]["FREE_SPACE"].update(max_action_age_ms=1e303)),
         "phases.FREE_SPACE.max_action_age_ms"),
        ("cartesian without a model", mutate(lambda d: d["session"].update(CARTESIAN)),
         "robot: needs 'kinematics'"),
        ("unknown kinematic model", mutate(lambda d: d["robot"].update(kinematics="kuka")),
         "robot.kinematics: unknown model 'kuka'"),
        ("cartesian units", mutate(lambda d: (d["robot"].update(kinematics="ur5e"),
                                              d["session"].update(CARTESIAN, action_units="rad"))),
         "session.action_units"),
        ("cartesian width", mutate(lambda d: (d["robot"].update(kinematics="ur5e"),
                                              d["session"].update(CARTESIAN, action_dim=6))),
         "session.action_dim: must be 3"),
        ("joint-space width", mutate(lambda d: d["session"].update(action_dim=1)),
         "session.action_dim: must be 6"),
        ("workspace inverted", mutate(lambda d: d["robot"].update(
            workspace={"lower": [0.0, 0.0, 1.0], "upper": [1.0, 1.0, 0.0]})),
         "robot.workspace.lower[2]"),
        ("period below a nanosecond", mutate(
            lambda d: d["timing"].update(control_period_ms=1e-9)), "timing.control_period_ms"),
    ]


@pytest.mark.parametrize("case,doc,needle", _mutations(), ids=[m[0] for m in _mutations()])
def test_invalid_scenario_exits_2_naming_the_problem(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str, doc: object, needle: str
) -> None:
    path = _write(tmp_path, doc)
    assert main(["replay", str(path)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert str(path) in captured.err
    assert needle in captured.err
    assert "Traceback" not in captured.err


def test_missing_file_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(tmp_path / "absent.json")]) == 2
    assert "cannot read file" in capsys.readouterr().err


def test_bad_chunks_are_refusals_not_errors(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    doc = _seed()
    doc["events"].append({"t": 400, "kind": "chunk", "chunk_id": "X", "actions": "lots"})
    doc["events"].append({"t": 401, "kind": "chunk"})
    doc["until"] = 402
    assert main(["replay", str(_write(tmp_path, doc))]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    refused = [line for line in lines if line["kind"] == "chunk" and line["t"] >= 400]
    assert [line["reasons"] for line in refused] == [["MALFORMED"], ["MALFORMED"]]
