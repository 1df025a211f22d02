"""Losing a camera (kernel/core/cameras.py), beyond the catalog's three scenarios: a hold it
caused comes back after a recovery while the camera is still down, and ends with it; a report
of a camera the configuration does not have changes nothing; and the ``cameras`` section fails
closed."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from kernel.core.lines import CameraLine, TransitionLine
from kernel.replay import Replay
from kernel.scenario.fields import ScenarioError
from kernel.scenario.load import load_scenario
from tools.scenarios import catalog_cameras


def _replay(tmp_path: Path, events: list[dict[str, Any]], until: float = 100,
            cameras: list[dict[str, Any]] | None = None) -> list[Any]:
    spec = catalog_cameras.camera_lost_stops_the_phase()
    doc = spec.document()
    doc["events"] = sorted([*doc["events"][:-4], *events], key=lambda e: e["t"])  # C1, no states
    doc["until"] = until
    if cameras is not None:
        doc["cameras"] = cameras
    path = tmp_path / "s.json"
    path.write_text(json.dumps(doc))
    return list(Replay(load_scenario(path)).lines())


def _fallback(lines: list[Any]) -> list[tuple[float, str, str]]:
    return [(float(line.t), str(line.to), str(line.trigger)) for line in lines
            if isinstance(line, TransitionLine) and line.machine == "fallback"]


def _camera(t: float, status: str, name: str = "wrist_rgb") -> dict[str, Any]:
    return {"t": t, "kind": "camera", "camera": name, "status": status}


def _operator(t: float) -> dict[str, Any]:
    return {"t": t, "kind": "operator", "action": "accept_recovery"}


def test_a_recovery_while_the_camera_is_down_holds_again_and_one_after_it_is_back_runs(
        tmp_path: Path) -> None:
    lines = _replay(tmp_path, [_camera(30, "lost"), _operator(40), _camera(60, "back"),
                               _operator(70)])
    assert _fallback(lines) == [
        (30.0, "SAFE_HOLD", "CAMERA_LOST"), (40.0, "RUNNING", "RECOVERY_ACCEPTED"),
        (40.0, "SAFE_HOLD", "CAMERA_LOST"),  # the next tick: the camera is still down
        (70.0, "RUNNING", "RECOVERY_ACCEPTED")]


def test_a_second_cause_while_down_and_an_unknown_camera_change_nothing(
        tmp_path: Path) -> None:
    lines = _replay(tmp_path, [_camera(25, "lost", "scene_rgb"), _camera(30, "frozen",
                                                                         "scene_rgb"),
                               _camera(35, "lost", "thermal")], until=60)
    cameras = [line for line in lines if isinstance(line, CameraLine)]
    assert [(c.camera, c.status, c.on_loss) for c in cameras] == [
        ("scene_rgb", "lost", "continue"), ("thermal", "lost", "none")]
    assert cameras[1].detail == "not a camera of this configuration"
    assert _fallback(lines) == []  # within scene_rgb's 100 ms grace


@pytest.mark.parametrize(("cameras", "problem"), [
    ([{"name": "thermal"}], "cameras.0.name: 'thermal' is not one of session.observation_keys"),
    ([{"name": "wrist_rgb"}, {"name": "wrist_rgb"}], "cameras.1.name: 'wrist_rgb' is named twice"),
    ([{"name": "wrist_rgb", "on_loss": "continue"}], "cameras.0.grace_ms: on_loss"),
    ([{"name": "wrist_rgb", "grace_ms": 10}], "cameras.0.grace_ms: on_loss = \"stop\""),
    ([{"name": "wrist_rgb", "on_loss": "continue", "grace_ms": 9000}],
     "cameras.0.grace_ms: must be at most 5000"),
    ([{"name": "wrist_rgb", "lens": "wide"}], "cameras.0.lens: unknown key"),
    ([{"name": "wrist_rgb", "on_loss": "pause"}], "cameras.0.on_loss: unknown value"),
    ({"name": "wrist_rgb"}, "cameras: must be a list"),
])
def test_the_cameras_section_fails_closed(tmp_path: Path, cameras: Any, problem: str) -> None:
    with pytest.raises(ScenarioError) as caught:
        _replay(tmp_path, [], cameras=cameras)
    assert problem in str(caught.value).replace("[", ".").replace("]", ""), str(caught.value)
