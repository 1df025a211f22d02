"""Speed caps of the classical owners, on the core alone (before, each was caught only by a
whole-cell test; issue 15, item 14):

- the planner moves no joint faster than ``motion.planner_velocity``, below the joint limits;
- the contact law's targets move no joint faster than its velocity limit (a trial's
  ``speed_scale`` lowers the limits below what the law's descent asks of a wrist).
"""

from __future__ import annotations

import numpy as np

from kernel.config.build import build_config
from kernel.core.events import InsertEvent, MoveEvent
from kernel.scenario.fields import Where
from skills.contact import ContactState
from tests.core.test_motion import Drive
from tools.scenarios.base import Q0, ScenarioSpec

SLOW = 0.02
"""rad/s on every joint: far below what a 3 cm/s descent asks of the UR5e's joints."""


def _drive(phase: str, cards: dict, robot: dict, motion: dict | None = None) -> Drive:
    spec = ScenarioSpec(name="caps", description="", events=[], until=0, expect=[],
                        phase=phase, phases=cards,
                        timing={"control_period_ms": 2, "clock_uncertainty_ms": 0})
    doc = spec.document()
    doc["robot"].update(robot)
    if motion is not None:
        doc["motion"] = motion
    return Drive(build_config(doc, Where("caps", "")))


def _fastest(drive: Drive, start: int = 0) -> np.ndarray:
    """Each joint's fastest commanded speed over the run (rad/s)."""
    steps = np.abs(np.diff(drive.positions(start), axis=0))
    return steps.max(axis=0) / (drive.period * 1e-9)


def test_the_planner_moves_no_joint_faster_than_its_velocity_cap() -> None:
    cap = 0.5  # a 0.6 rad move at the planner's 6 rad/s² would reach 1.9 rad/s uncapped
    drive = _drive("FREE_SPACE", {"FREE_SPACE": {"executor": "planner"}}, {},
                   {"planner_velocity": cap})
    assert np.all(drive.core.config.limits.velocity[:6] > cap)  # the cap is the bound here
    target = np.array(Q0) + np.array([0.6, -0.4, 0.0, 0.0, 0.0, 0.0])
    drive.feed(MoveEvent, move_id=1, target=tuple(target.tolist()))
    drive.tick(900)
    assert np.allclose(drive.motions[-1].q, target, atol=1e-6)  # it got there
    fastest = _fastest(drive)
    assert fastest.max() <= cap * (1 + 1e-6), fastest
    assert fastest.max() >= 0.9 * cap  # and a long move does reach its cruise


def test_contact_targets_move_no_joint_faster_than_its_velocity_limit() -> None:
    drive = _drive("CONTACT", {"CONTACT": {"executor": "contact"}},
                   {"kinematics": "ur5e", "velocity_limits": [SLOW] * 6})
    drive.tick(follow=True)
    kinematics, arm = drive.core.config.kinematics, drive.core.config.limits.arm_mask
    pose = kinematics.forward(drive.core.inspect_state().measured_q[arm])
    drive.feed(InsertEvent, xy=tuple(pose.position[:2]), z_end=float(pose.position[2]) - 0.05,
               rotation=tuple(pose.rotation.ravel()))
    start = len(drive.motions)
    drive.tick(200, follow=True)
    assert drive.core.status().contact is ContactState.DESCENDING
    fastest = _fastest(drive, start - 1)
    assert fastest.max() <= SLOW * (1 + 1e-6), fastest
    assert fastest.max() >= 0.5 * SLOW  # the descent does move, at the cap
