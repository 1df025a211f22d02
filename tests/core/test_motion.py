"""Motion inside the core: what reaches the arm is the core's, on the core's own period.

Every test drives a real :class:`~kernel.core.runtime.Core` through events only (moves, the
gripper, chunks, fallbacks) and reads the motion effect of each tick: stops always reach the
device, the first command holds where the arm was measured, a paused planner move resumes
without a jerk step, and the same motion takes the same time at 2, 4 and 8 ms periods.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from kernel.config.build import build_config
from kernel.core.config import CoreConfig
from kernel.core.effects import Compute, Hold, Retreat, Setpoint, Step, Stop
from kernel.core.events import (
    ComputedEvent,
    Event,
    GripperEvent,
    InsertEvent,
    MoveEvent,
    ObservationEvent,
    OperatorEvent,
    PhaseEvent,
    StateEvent,
    TickEvent,
)
from kernel.core.jobs import run_job
from kernel.core.lines import ChunkLine, MotionLine
from kernel.core.runtime import Core
from kernel.scenario.fields import Where
from skills.contact import ContactState
from skills.phases import TaskPhase
from skills.planner import MoveStatus
from tests.runtime.machine_setup import chunk_event, chunk_fields
from tools.scenarios.base import Q0, ScenarioSpec

MS = 1_000_000
V, A = 3.14, 40.0
PLANNER = {"executor": "planner"}


def config(period_ms: float = 2, phase: str = "FREE_SPACE", executor: str | None = "planner",
           **robot: Any) -> CoreConfig:
    phases: dict[str, Any] = {"FREE_SPACE": {"max_observation_age_ms": 80,
                                             "max_action_age_ms": 2000, "max_projection": 0.02},
                              "CONTACT": {"force_band": 15.0}}
    if executor is not None:
        phases["FREE_SPACE"]["executor"] = executor
    spec = ScenarioSpec(name="motion", description="", events=[], until=0, expect=[],
                        phase=phase, phases=phases,
                        timing={"control_period_ms": period_ms, "clock_uncertainty_ms": 0})
    doc = spec.document()
    doc["robot"].update(robot)
    return build_config(doc, Where("motion", ""))


class Drive:
    """A core and a clock: feed events now, tick one period at a time, keep every effect."""

    def __init__(self, cfg: CoreConfig) -> None:
        self.core = Core(cfg)
        self.period = cfg.control_period_ns
        self.t = 0
        self.motions: list[Any] = []
        self.lines: list[Any] = []

    def feed(self, make: Any, **fields: Any) -> Step:
        return self.event(make(t=self.t, **fields))

    def event(self, event: Event) -> Step:
        """Apply ``event``; a job the core asks for runs at once (as in a scenario replay)."""
        step = self.core.step(event)
        self.lines += step.lines
        for effect in step.effects:
            if isinstance(effect, Compute):
                cfg = self.core.config
                result = run_job(effect.job, cfg.limits, cfg.cartesian)
                step = self.event(ComputedEvent(t=event.t, result=result))
        return step

    def tick(self, n: int = 1, follow: bool = False) -> Any:
        """``n`` control ticks; with ``follow``, an arm that tracks every setpoint exactly
        reports its state before each tick."""
        for _ in range(n):
            last = self.motions[-1] if self.motions else None
            if follow and isinstance(last, Setpoint | Retreat):
                self.event(StateEvent(t=self.t, q=last.q))
            step = self.core.step(TickEvent(t=self.t))
            self.lines += step.lines
            self.motions.append(step.motion)
            self.t += self.period
        return self.motions[-1]

    def positions(self, start: int = 0) -> np.ndarray:
        return np.array([m.q for m in self.motions[start:]])


def test_the_first_command_holds_where_the_arm_was_measured() -> None:
    drive = Drive(config(executor=None, phase="IDLE"))
    parked = np.array(Q0) + np.array([0.3, -0.2, 0.25, 0.1, -0.15, 0.2])
    drive.feed(StateEvent, q=tuple(parked))
    first = drive.tick()
    assert isinstance(first, Setpoint) and np.allclose(first.q, parked)
    drive.tick(100)
    assert np.allclose(drive.motions[-1].q, parked)


@pytest.mark.parametrize("measured", [[1.0002, 0.0, -1.003, 0.0, 0.0, 0.0],
                                      [6.4, 0.0, 0.2, -6.5, 0.0, 0.0]],
                         ids=["a-hair-past", "far-past"])
def test_a_stop_reaches_the_device_whatever_was_measured(measured: list[float]) -> None:
    drive = Drive(config(executor=None))
    drive.tick()
    drive.feed(StateEvent, q=tuple(measured))
    drive.feed(OperatorEvent, action="estop")
    stop = drive.tick()
    assert isinstance(stop, Stop)
    commanded = drive.core.inspect_state().motion.commanded
    limits = drive.core.config.limits
    assert np.all(commanded >= limits.lower) and np.all(commanded <= limits.upper)


def test_a_takeover_gives_the_device_its_own_hold() -> None:
    drive = Drive(config(executor=None))
    drive.tick()
    drive.feed(OperatorEvent, action="takeover")
    assert isinstance(drive.tick(), Hold)


def test_the_gripper_rides_on_every_command() -> None:
    drive = Drive(config(executor=None))
    assert drive.tick().gripper is None
    drive.feed(GripperEvent, opening=0.04)
    assert drive.tick().gripper == 0.04
    drive.feed(OperatorEvent, action="estop")
    assert drive.tick().gripper == 0.04  # a stop never drops a held part
    drive.feed(GripperEvent, opening=-1.0)
    assert drive.lines[-1] == MotionLine(t=drive.lines[-1].t, request="gripper",
                                         decision="refused", detail="opening -1.0 is not a "
                                         "distance")


def _moved(drive: Drive, target: np.ndarray, move_id: int = 1) -> None:
    drive.feed(MoveEvent, move_id=move_id, target=tuple(target.tolist()))


def test_a_planner_move_reaches_its_target_and_reports_it() -> None:
    drive = Drive(config())
    target = np.array(Q0) + np.array([0.4, -0.3, 0.2, 0.0, 0.1, 0.0])
    _moved(drive, target)
    drive.tick(1500)
    status = drive.core.status()
    assert (status.move_id, status.move) == (1, MoveStatus.FINISHED)
    assert np.allclose(drive.motions[-1].q, target, atol=1e-9)
    planned = [line for line in drive.lines if isinstance(line, MotionLine)]
    assert planned[0].decision == "planned" and planned[0].duration_ms > 0


def test_a_move_outside_the_limits_is_refused_with_a_line() -> None:
    drive = Drive(config())
    _moved(drive, np.array([9.0, 0, 0, 0, 0, 0]))
    drive.tick()
    refused = [line for line in drive.lines if isinstance(line, MotionLine)]
    assert refused[0].decision == "refused" and "limits" in refused[0].detail
    assert drive.core.status().move is MoveStatus.NONE


@pytest.mark.parametrize(("moving", "held"), [(150, 400), (179, 1), (60, 7), (300, 30)],
                         ids=["long-hold", "one-tick", "accelerating", "braking"])
def test_a_paused_planner_move_resumes_within_the_limits(moving: int, held: int) -> None:
    """Interrupted at any point of its profile, for any time, the move resumes without a step
    in velocity or acceleration: the discrete jerk stays within the owners' jerk limits."""
    drive = Drive(config())
    target = np.array(Q0) + np.array([0.9, 0.0, 0.0, 0.0, 0.0, 0.0])
    _moved(drive, target)
    drive.tick(moving)
    drive.feed(PhaseEvent, to=TaskPhase.SAFE_HOLD, evidence={})  # a fallback takes the tick
    drive.tick(held)
    drive.feed(OperatorEvent, action="accept_recovery")  # back to work through VALIDATE
    drive.tick(2500)
    assert str(drive.core.status().phase) == "FREE_SPACE"
    q = drive.positions()
    dt = drive.period * 1e-9
    motion = drive.core.config.motion
    jerk = np.abs(np.diff(q, n=3, axis=0)).max() / dt**3
    assert jerk <= max(motion.interpolator_jerk, motion.planner_jerk) * 1.05
    assert np.abs(np.diff(q, n=2, axis=0)).max() / dt**2 <= A * 1.05
    assert np.allclose(q[-1], target, atol=1e-6)  # and the move still reaches its target


def test_contact_without_a_model_holds_and_refuses_a_descent() -> None:
    drive = Drive(config(executor=None, phase="CONTACT"))
    drive.tick()
    drive.feed(InsertEvent, xy=(0.0, 0.0), z_end=0.1, rotation=tuple(np.eye(3).ravel()))
    held = drive.tick(10)
    assert isinstance(held, Setpoint) and str(held.owner) == "contact"
    assert np.allclose(held.q, Q0) and held.stiffness  # compliant, where contact began
    assert drive.lines[-1].decision == "refused" if isinstance(drive.lines[-1], MotionLine) \
        else any(isinstance(line, MotionLine) and line.decision == "refused"
                 for line in drive.lines)
    assert drive.core.status().contact is ContactState.HOLDING


def test_a_contact_fallback_retreats_compliantly() -> None:
    drive = Drive(config(executor=None, phase="CONTACT"))
    drive.tick()
    drive.feed(StateEvent, q=tuple(Q0), force_residual=40.0)  # outside the card's force band
    retreat = drive.tick()
    assert isinstance(retreat, Retreat) and str(retreat.owner) == "contact"


# -- periods -----------------------------------------------------------------------------------

PERIODS_MS = (2, 4, 8)


def _arrival_s(drive: Drive, target: np.ndarray, start: int, tolerance: float) -> float:
    q = drive.positions(start)
    close = np.flatnonzero(np.abs(q - target).max(axis=1) <= tolerance)
    assert close.size, f"never reached the target at {drive.period / MS} ms"
    return float(close[0]) * drive.period * 1e-9


@pytest.mark.parametrize("distance", [0.5, 0.05])
def test_a_planner_move_takes_the_same_time_at_any_period(distance: float) -> None:
    arrivals = []
    for period in PERIODS_MS:
        drive = Drive(config(period))
        target = np.array(Q0) + distance
        _moved(drive, target)
        drive.tick(math.ceil(3000 / period))
        arrivals.append(_arrival_s(drive, target, 0, 1e-6))
    assert max(arrivals) - min(arrivals) <= max(PERIODS_MS) / 1000, arrivals


def test_a_policy_stream_moves_at_the_speed_it_asks_at_any_period() -> None:
    """The interpolator runs on the core's period: 1 s of 8 ms ticks toward a target 0.5 rad
    away along a 0.5 rad/s stream gets there when 2 ms ticks do (it used to reach 0.1 rad)."""
    arrivals = []
    for period in PERIODS_MS:
        drive = Drive(config(period, executor="policy"))
        drive.event(ObservationEvent(t=0, observation_id="O1"))
        steps = np.arange(1, 101)[:, None] * 0.005  # 100 actions of 10 ms at 0.5 rad/s
        actions = np.array(Q0) + steps * np.array([1.0, 0, 0, 0, 0, 0])
        drive.event(chunk_event(0, chunk_fields("C1", 1, 0, "FREE_SPACE", "O1", 0, 10,
                                                actions)))
        (decision,) = [line for line in drive.lines if isinstance(line, ChunkLine)]
        assert decision.decision == "accepted", decision
        drive.tick(math.ceil(1600 / period), follow=True)
        arrivals.append(_arrival_s(drive, actions[-1], 0, 1e-3))
    assert max(arrivals) - min(arrivals) <= max(PERIODS_MS) / 1000, arrivals
    assert 0.9 < arrivals[0] < 1.2  # the last action is due at 1.01 s
