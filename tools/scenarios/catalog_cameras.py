"""Scenarios for losing a camera (kernel/core/cameras.py): the wrist camera stops the phase at
once, the scene camera may be gone for a grace. C1 (4 actions from 20 ms) answers O1, which
carried both cameras' frames; requests are retried every 10 ms, so a request that is not made
while a camera is down is one the core held back."""

from __future__ import annotations

from typing import Any

from tools.scenarios.base import Q0, ScenarioSpec, chunk, observation, ramp, session
from tools.scenarios.base import state as st

CAMERAS = ["wrist_rgb", "scene_rgb"]


def _cameras(grace_ms: float) -> list[dict[str, Any]]:
    return [{"name": "wrist_rgb", "on_loss": "stop"},
            {"name": "scene_rgb", "on_loss": "continue", "grace_ms": grace_ms}]


def _start() -> list[dict[str, Any]]:
    o1 = observation(0, "O1")
    o1["frames"] = [{"camera": name, "t_capture": 0, "digest": f"{index:032x}",
                     "calibration_epoch": "cal-12"} for index, name in enumerate(CAMERAS)]
    following = [st(30 + 10 * k, q) for k, q in enumerate(ramp(1, 4))]
    return [st(0, list(Q0)), o1, chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 4)),
            *following]


def _camera(t: float, name: str, status: str, detail: str = "") -> dict[str, Any]:
    event = {"t": t, "kind": "camera", "camera": name, "status": status}
    return {**event, "detail": detail} if detail else event


def _spec(name: str, description: str, grace_ms: float, events: list[dict[str, Any]],
          until: float, expect: list[dict[str, Any]],
          forbid: list[dict[str, Any]]) -> ScenarioSpec:
    return ScenarioSpec(name=name, description=description, events=[*_start(), *events],
                        until=until, expect=expect, forbid=forbid,
                        timing={"request_retry_ms": 10}, cameras=_cameras(grace_ms),
                        session={**session(), "protocol": [3, 3]})  # frames travel in 3


def camera_lost_stops_the_phase() -> ScenarioSpec:
    return _spec(
        "camera_lost_stops_the_phase",
        "The wrist camera stops giving frames while C1 runs, and losing it stops the phase: "
        "SAFE_HOLD (CAMERA_LOST) at once, and no observation is requested after it.",
        100.0, [_camera(35, "wrist_rgb", "lost", "no frame for 31 ms")], 100,
        expect=[{"kind": "camera", "t": 35, "camera": "wrist_rgb", "status": "lost",
                 "on_loss": "stop"},
                {"kind": "transition", "machine": "fallback", "from": "RUNNING",
                 "to": "SAFE_HOLD", "trigger": "CAMERA_LOST", "t": 35}],
        forbid=[{"kind": "tick", "t_min": 36, "command": "setpoint"},
                {"kind": "request", "t_min": 35}])


def camera_lost_within_grace() -> ScenarioSpec:
    return _spec(
        "camera_lost_within_grace",
        "The scene camera is lost for 30 ms; the phase may go on without it for 100 ms: C1 "
        "runs to its end, no observation is requested until the camera is back (at 10 ms "
        "retries there would have been three), and nothing holds.",
        100.0, [_camera(25, "scene_rgb", "lost"), _camera(55, "scene_rgb", "back")], 58,
        expect=[{"kind": "camera", "t": 25, "camera": "scene_rgb", "status": "lost",
                 "on_loss": "continue", "grace_ms": 100},
                {"kind": "tick", "t": 50, "command": "setpoint", "sent.chunk_id": "C1"},
                {"kind": "camera", "t": 55, "camera": "scene_rgb", "status": "back"},
                {"kind": "request", "t": 56}],
        forbid=[{"kind": "transition", "machine": "fallback"},
                {"kind": "request", "t_min": 25, "t_max": 54}])


def camera_lost_past_grace() -> ScenarioSpec:
    return _spec(
        "camera_lost_past_grace",
        "The scene camera froze and stays frozen past the 20 ms the phase may go on without "
        "it: SAFE_HOLD (CAMERA_LOST) at the first tick after its grace ran out.",
        20.0, [_camera(25, "scene_rgb", "frozen", "30 identical frames")], 100,
        expect=[{"kind": "camera", "t": 25, "camera": "scene_rgb", "status": "frozen",
                 "on_loss": "continue", "grace_ms": 20},
                {"kind": "transition", "machine": "fallback", "from": "RUNNING",
                 "to": "SAFE_HOLD", "trigger": "CAMERA_LOST", "t": 46}],
        forbid=[{"kind": "transition", "machine": "fallback", "t_max": 44}])


SCENARIOS = (camera_lost_stops_the_phase, camera_lost_within_grace, camera_lost_past_grace)
