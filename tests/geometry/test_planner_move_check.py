"""A planned move waits for its own clearance check, never for another move's.

Found in the simulated cell's second cycle: a resumed move asked for a clearance job, then the
task asked for the next move before the job answered; the answer (for the old move) cleared a
move that was no longer there, and the new move was never planned nor checked: the planner held
the arm still until the cycle's time ran out.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from kernel.config.build import build_config
from kernel.core.effects import Compute, Setpoint
from kernel.core.events import ComputedEvent, MoveEvent, StateEvent, TickEvent
from kernel.core.jobs import ClearanceJob, run_job
from kernel.core.lines import MotionLine
from kernel.core.runtime import Core
from kernel.scenario.fields import Where
from skills.planner import MoveStatus
from tools.scenarios.base import ScenarioSpec, session
from tools.scenarios.catalog_collision import GEOMETRY, WRIST_START, _robot

HIGH = [0.0414, -1.7316, 2.0356, -1.8748, -1.5708, 0.0414]
"""The TCP 20 cm above the table, far from every solid."""


def _core() -> Core:
    spec = ScenarioSpec(name="moves", description="", events=[], until=0, expect=[],
                        robot=_robot(), geometry=GEOMETRY,
                        phases={"FREE_SPACE": {"executor": "planner"}},
                        session=session(phase="FREE_SPACE", state=list(HIGH)))
    return Core(build_config(spec.document(), Where("moves", "")))


class Cell:
    """A core whose jobs wait until the test answers them."""

    def __init__(self) -> None:
        self.core = _core()
        self.t = 0
        self.asked: list[ClearanceJob] = []
        self.lines: list[Any] = []
        self.last: Any = None

    def step(self, event: Any) -> None:
        step = self.core.step(event)
        self.lines += step.lines
        self.asked += [e.job for e in step.effects
                       if isinstance(e, Compute) and isinstance(e.job, ClearanceJob)]
        if step.motion is not None:
            self.last = step.motion

    def tick(self, n: int = 1) -> None:
        for _ in range(n):
            if isinstance(self.last, Setpoint):  # an arm that follows every setpoint
                self.step(StateEvent(t=self.t, q=self.last.q))
            self.step(TickEvent(t=self.t))
            self.t += self.core.config.control_period_ns

    def answer(self, job: ClearanceJob) -> None:
        config = self.core.config
        self.step(ComputedEvent(t=self.t, result=run_job(job, config.limits, None,
                                                         config.collision)))


def test_a_new_move_is_checked_and_played_though_the_last_ones_check_answers_late() -> None:
    cell = Cell()
    cell.step(StateEvent(t=0, q=tuple(HIGH)))
    first = np.array(HIGH) + np.array([0.2, 0.0, 0.0, 0.0, 0.0, 0.0])
    cell.step(MoveEvent(t=0, move_id=1, target=tuple(first.tolist())))
    cell.tick(50)
    [pending] = cell.asked  # the first move waits for its check
    second = np.array(HIGH) + np.array([-0.2, 0.0, 0.0, 0.0, 0.0, 0.0])
    cell.step(MoveEvent(t=cell.t, move_id=2, target=tuple(second.tolist())))
    cell.tick(5)
    cell.answer(pending)  # the first move's answer, after the second was asked for
    cell.tick(50)
    assert len(cell.asked) == 2, "the second move was never checked"
    assert np.allclose(cell.asked[1].rows[-1], second)
    cell.answer(cell.asked[1])
    cell.tick(2500)
    status = cell.core.status()
    assert (status.move_id, status.move) == (2, MoveStatus.FINISHED)
    assert np.allclose(cell.last.q, second, atol=1e-9)
    planned = [line.move_id for line in cell.lines
               if isinstance(line, MotionLine) and line.decision == "planned"]
    assert planned == [2]


def test_a_move_waits_for_its_own_check_not_for_the_answer_to_an_earlier_one() -> None:
    """The first move's clear answer plays nothing of the second, which waits at rest for its
    own check (towards the folded wrist: a move that must not play unchecked)."""
    cell = Cell()
    cell.step(StateEvent(t=0, q=tuple(HIGH)))
    first = np.array(HIGH) + np.array([0.1, 0.0, 0.0, 0.0, 0.0, 0.0])
    cell.step(MoveEvent(t=0, move_id=1, target=tuple(first.tolist())))
    cell.tick(50)
    [pending] = cell.asked
    cell.step(MoveEvent(t=cell.t, move_id=2, target=tuple(WRIST_START)))
    cell.answer(pending)
    cell.tick(200)
    assert len(cell.asked) == 2 and np.allclose(cell.asked[1].rows[-1], WRIST_START)
    assert not [line for line in cell.lines
                if isinstance(line, MotionLine) and line.decision == "planned"]
    assert np.allclose(cell.last.q, HIGH, atol=1e-9)
    assert cell.core.status().move is MoveStatus.WAITING
