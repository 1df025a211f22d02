"""A trial's envelope, enforced by the core: the tool never commanded out of the box, a measured
breach or a force over the limit stops the arm (ENVELOPE → CONTROLLER_STOP)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from kernel.config.build import build_config
from kernel.core.effects import Setpoint, Stop
from kernel.core.events import MoveEvent, StateEvent, TickEvent
from kernel.core.lines import TransitionLine
from kernel.core.runtime import Core
from kernel.model_file import BUILTIN
from kernel.robot_model import load_kinematics
from kernel.scenario.fields import ScenarioError, Where
from tools.scenarios.base import ScenarioSpec

MS = 1_000_000
HOME = np.array([0.0, -1.5707963267948966, 1.5707963267948966, -1.5707963267948966,
                 -1.5707963267948966, 0.0])
KIN = load_kinematics(BUILTIN["ur5e"], 6)
TCP = KIN.forward(HOME).position


def _doc(envelope: dict[str, Any] | None, **robot: Any) -> dict[str, Any]:
    spec = ScenarioSpec(name="trial", description="", events=[], until=0, expect=[],
                        phase="FREE_SPACE", phases={"FREE_SPACE": {"executor": "planner"}})
    doc = spec.document()
    doc["robot"].update({"kinematics": "ur5e", **robot})
    doc["session"]["state"] = HOME.tolist()
    if envelope is not None:
        doc["envelope"] = envelope
    return doc


def _core(margin: float = 0.05, force: float = 30.0) -> Core:
    box = {"lower": (TCP - margin).tolist(), "upper": (TCP + margin).tolist()}
    return Core(build_config(_doc({"workspace": box, "max_wrist_force_n": force}),
                             Where("trial", "")))


def _fallbacks(lines: list[Any]) -> list[TransitionLine]:
    return [line for line in lines if isinstance(line, TransitionLine)
            and line.machine == "fallback"]


def test_a_move_out_of_the_box_stops_at_its_edge_and_is_never_sent_past_it() -> None:
    core = _core(margin=0.05)
    core.step(StateEvent(t=0, q=tuple(HOME)))
    target = HOME + np.array([0.6, 0.0, 0.0, 0.0, 0.0, 0.0])  # the tool swings 25 cm away
    core.step(MoveEvent(t=0, move_id=1, target=tuple(target)))
    lines, motions = [], []
    for k in range(1500):
        step = core.step(TickEvent(t=k * 2 * MS))
        lines += step.lines
        motions.append(step.motion)
    sent = [m for m in motions if isinstance(m, Setpoint)]
    assert sent and all(
        np.all(np.abs(KIN.forward(np.array(m.q)).position - TCP) <= 0.05 + 1e-12) for m in sent)
    (stop,) = _fallbacks(lines)
    assert (stop.to, stop.trigger) == ("CONTROLLER_STOP", "ENVELOPE")
    assert isinstance(motions[-1], Stop)


def test_a_measured_tool_out_of_the_box_stops_the_arm() -> None:
    core = _core(margin=0.05)
    outside = HOME + np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0])
    lines = core.step(StateEvent(t=0, q=tuple(outside))).lines
    assert [(t.to, t.trigger) for t in _fallbacks(list(lines))] == [
        ("CONTROLLER_STOP", "ENVELOPE")]
    assert isinstance(core.step(TickEvent(t=0)).motion, Stop)


@pytest.mark.parametrize(("force", "stops"), [(29.9, False), (30.1, True), (-30.1, True)])
def test_the_wrist_force_limit(force: float, stops: bool) -> None:
    core = _core(force=30.0)
    lines = core.step(StateEvent(t=0, q=tuple(HOME), force_residual=force)).lines
    assert bool(_fallbacks(list(lines))) is stops


def test_without_an_envelope_nothing_is_bounded_by_it() -> None:
    core = Core(build_config(_doc(None), Where("trial", "")))
    outside = HOME + np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert not _fallbacks(list(core.step(StateEvent(t=0, q=tuple(outside),
                                                    force_residual=500.0)).lines))


@pytest.mark.parametrize(("envelope", "needle"), [
    ({"workspace": {"lower": [0, 0, 0], "upper": [1, 1, 1]}, "max_wrist_force_n": 10,
      "max_force": 3}, "envelope.max_force: unknown key"),
    ({"workspace": {"lower": [0, 0, 1], "upper": [1, 1, 0]}, "max_wrist_force_n": 10},
     "envelope.workspace.lower[2]"),
    ({"workspace": {"lower": [0, 0, 0], "upper": [1, 1, 1]}}, "max_wrist_force_n"),
])
def test_a_bad_envelope_is_named(envelope: dict[str, Any], needle: str) -> None:
    with pytest.raises(ScenarioError, match=needle.replace("[", r"\[").replace("]", r"\]")):
        build_config(_doc(envelope), Where("trial", ""))


def test_an_envelope_needs_the_arms_model() -> None:
    doc = _doc({"workspace": {"lower": [0, 0, 0], "upper": [1, 1, 1]}, "max_wrist_force_n": 1})
    del doc["robot"]["kinematics"]
    with pytest.raises(ScenarioError, match="envelope: needs the arm's model"):
        build_config(doc, Where("trial", ""))
