"""The assembly cycle's approach timeout counts the policy's time only: while a fallback holds
the arm (a human recovering on a real device, a reconnection), the approach's clock is paused,
so a recovery that takes longer than the timeout does not cost the cycle."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from assurance.fallback import Mode
from kernel.app.task import assembly_runner
from skills.assembly import AssemblyRunner, AssemblyStep, MoveRequest, PhaseRequest, Sensed
from skills.contact import ContactState, DescentStatus
from skills.phases import TaskPhase
from skills.planner import MoveStatus
from skills.trajectory import MotionLimits
from tests.cell.harness import manifest

TICK_NS = 100_000_000  # the runner is asked every 0.1 s here: its requests' own interval


@dataclass(frozen=True, slots=True)
class _View:
    mode: Mode
    phase: TaskPhase = TaskPhase.PRE_CONTACT
    move_id: int = 0
    move: MoveStatus = MoveStatus.NONE
    contact: ContactState = ContactState.IDLE
    descent: DescentStatus = DescentStatus.NONE


@pytest.fixture
def runner() -> AssemblyRunner:
    loaded = manifest("sim-ur5e.toml")
    kinematics = loaded.core.kinematics
    assert kinematics is not None
    limits = MotionLimits(kinematics.lower, kinematics.upper, np.full(6, 3.0), np.full(6, 6.0),
                          np.full(6, 60.0))
    runner = assembly_runner(loaded, kinematics, limits, None)
    runner._enter(AssemblyStep.APPROACH, 0)  # the policy's approach has begun
    return runner


def _drive(runner: AssemblyRunner, start_s: float, seconds: float, mode: Mode) -> list:
    """Ticks of the approach, far from the hole and moving (it never asks for CONTACT)."""
    asked = []
    for k in range(round(seconds * 1e9 / TICK_NS)):
        t_ns = round(start_s * 1e9) + (k + 1) * TICK_NS
        sensed = Sensed(t_ns=t_ns, q=np.zeros(6), qd=np.full(6, 0.2), force_norm=0.0,
                        fresh=True, driver_ok=True)
        asked += runner.update(sensed, _View(mode))
    return asked


def _gave_up(asked: list) -> bool:
    return any(isinstance(r, PhaseRequest) and r.to is TaskPhase.RETREAT for r in asked)


@pytest.mark.parametrize("fallback", [Mode.SAFE_HOLD, Mode.HUMAN_RECOVERY, Mode.DEGRADED])
def test_a_fallbacks_hold_does_not_count_against_the_approach(runner: AssemblyRunner,
                                                             fallback: Mode) -> None:
    limit_s = runner.timing.approach_timeout_s
    asked = _drive(runner, 0.0, limit_s - 2.0, Mode.RUNNING)
    asked += _drive(runner, limit_s - 2.0, 3 * limit_s, fallback)  # a long recovery
    asked += _drive(runner, 4 * limit_s - 2.0, 1.5, Mode.RUNNING)
    assert not _gave_up(asked) and runner.outcome is None
    asked = _drive(runner, 4 * limit_s - 0.5, 1.0, Mode.RUNNING)  # the policy's 8 s are up
    assert _gave_up(asked)
    assert runner.outcome is not None and runner.outcome.reason == "pre-contact approach timed out"


def test_the_approach_times_out_while_running(runner: AssemblyRunner) -> None:
    asked = _drive(runner, 0.0, runner.timing.approach_timeout_s + 0.5, Mode.RUNNING)
    assert _gave_up(asked)


CONTORTED = np.array([0.0414, 0.35, -0.7, -3.0, -1.5708, 0.0414])
"""Where the elbow press once left the arm after its approach timed out: the upper arm down at
the table, the tool turned up; no tool-down pose straight above it is reachable from here."""


def test_a_retreat_from_where_no_lift_is_reachable_goes_home_in_joint_space(
        runner: AssemblyRunner) -> None:
    """It crashed warden before (an uncaught PlanningError from the retreat lift's IK)."""
    runner._enter(AssemblyStep.RELEASE, 0)
    sensed = Sensed(t_ns=TICK_NS * 10, q=CONTORTED, qd=np.zeros(6), force_norm=0.0,
                    fresh=True, driver_ok=True)
    asked = runner.update(sensed, _View(Mode.RUNNING, phase=TaskPhase.RETREAT))
    [move] = [r for r in asked if isinstance(r, MoveRequest)]
    assert np.array_equal(move.target, runner.layout.home_q)
    assert runner.step is AssemblyStep.RETREAT_HOME
    assert "no retreat lift" in runner._failure


def test_a_refused_descent_gives_the_cycle_up_at_once(runner: AssemblyRunner) -> None:
    """Before, the task waited out the insertion's 4 s and then asked to verify a peg that
    never went in; the refusal's reason was nowhere in its outcome."""
    runner._enter(AssemblyStep.INSERT, 0)
    sensed = Sensed(t_ns=TICK_NS, q=np.zeros(6), qd=np.zeros(6), force_norm=0.0, fresh=True,
                    driver_ok=True)
    checking = _View(Mode.RUNNING, phase=TaskPhase.CONTACT, contact=ContactState.HOLDING,
                     descent=DescentStatus.CHECKING)
    assert not _gave_up(runner.update(sensed, checking))
    refused = _View(Mode.RUNNING, phase=TaskPhase.CONTACT, contact=ContactState.HOLDING,
                    descent=DescentStatus.REFUSED)
    assert _gave_up(runner.update(sensed, refused))
    assert runner.outcome is not None and "descent was refused" in runner.outcome.reason
