"""A core of the collision catalogue's cell whose clearance jobs wait until the test answers
them (run where the shell would run them: :func:`kernel.core.jobs.run_job`), and an arm that
follows every setpoint (and retreat target) exactly. Shared by the tests of what waits for a
check: a planned move (test_planner_move_check.py), the contact owner's descent
(test_descent_check.py) and its retreat (test_retreat_check.py)."""

from __future__ import annotations

from typing import Any

from kernel.config.build import build_config
from kernel.core.effects import Compute, Retreat, Setpoint
from kernel.core.events import ComputedEvent, StateEvent, TickEvent
from kernel.core.jobs import ClearanceJob, run_job
from kernel.core.runtime import Core
from kernel.scenario.fields import Where
from tools.scenarios.base import ScenarioSpec, session
from tools.scenarios.catalog_collision import GEOMETRY, _robot


class JobCell:
    def __init__(self, phase: str, executor: str, start: list[float],
                 card: dict[str, Any] | None = None,
                 geometry: dict[str, Any] | None = None) -> None:
        spec = ScenarioSpec(name="jobs", description="", events=[], until=0, expect=[],
                            robot=_robot(), geometry=geometry or GEOMETRY,
                            phases={phase: {"executor": executor, **(card or {})}},
                            session=session(phase=phase, state=list(start)))
        self.core = Core(build_config(spec.document(), Where("jobs", "")))
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
            if isinstance(self.last, Setpoint | Retreat):  # an arm that follows every target
                self.step(StateEvent(t=self.t, q=self.last.q))
            self.step(TickEvent(t=self.t))
            self.t += self.core.config.control_period_ns

    def answer(self, job: ClearanceJob) -> None:
        config = self.core.config
        self.step(ComputedEvent(t=self.t, result=run_job(job, config.limits, None,
                                                         config.collision)))
