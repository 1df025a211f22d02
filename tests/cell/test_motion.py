"""The motion layer: stops always reach the device, bring-up holds the parked pose, and a
planner move handed back after another owner resumes without a velocity step."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from assurance.fallback import Command as Cmd
from assurance.fallback import Owner
from drivers.base import Command, CommandKind
from kernel.cell.build import INTERPOLATOR_JERK, PLANNER_ACCELERATION, PLANNER_JERK
from kernel.cell.motion import MotionController
from kernel.cell.session import bring_up, open_run
from kernel.core.tick import TickCommand
from kernel.manifest import ClockKind
from kernel.shell.timer import VirtualClock
from skills.assembly import Sensed
from skills.planner import PlannedMove
from skills.trajectory import MotionLimits, plan_joint_move
from tests.cell.harness import manifest

PERIOD_NS = 2_000_000
INTERPOLATOR = MotionLimits.uniform(6, 1.0, 3.14, 20.0, INTERPOLATOR_JERK)
PLANNER = MotionLimits.uniform(6, 1.0, 2.0, PLANNER_ACCELERATION, PLANNER_JERK)
STOP = TickCommand(Cmd.STOP, Owner.SAFETY, None, None, None)
HUMAN = TickCommand(Cmd.HOLD, Owner.HUMAN, None, None, None)
PLANNER_TICK = TickCommand(Cmd.SETPOINT, Owner.PLANNER, None, None, None)


class _Runner:
    """The one thing the motion layer asks of the cycle runner: the planner's move."""

    gripper = 0.0

    def __init__(self, move: PlannedMove | None = None) -> None:
        self.move = move

    def planner_setpoint(self, dt_s: float) -> Any:
        return None if self.move is None else self.move.advance(dt_s)

    def resume_move_from(self, q: np.ndarray) -> None:
        if self.move is not None:
            self.move = PlannedMove(plan_joint_move(q, self.move.target, PLANNER))


def _sensed(t_ns: int, q: np.ndarray) -> Sensed:
    return Sensed(t_ns=t_ns, q=np.asarray(q, float), qd=np.zeros(6), force_norm=0.0,
                  fresh=True, driver_ok=True)


def _controller(runner: _Runner | None = None) -> MotionController:
    return MotionController(INTERPOLATOR, np.zeros(6), runner or _Runner(), None,  # type: ignore[arg-type]
                            PERIOD_NS)


@pytest.mark.parametrize("tick", [STOP, HUMAN], ids=["stop", "human-hold"])
@pytest.mark.parametrize("measured", [[1.0002, 0.0, -1.003, 0.0, 0.0, 0.0],
                                      [np.nan, 0.0, 0.2, np.inf, 0.0, 0.0]],
                         ids=["past-a-limit", "not-finite"])
def test_device_commands_survive_a_bad_measured_state(tick: TickCommand,
                                                      measured: list[float]) -> None:
    motion = _controller()
    command = motion.command(tick, _sensed(0, np.array(measured)))
    assert command.kind is (CommandKind.STOP if tick is STOP else CommandKind.HOLD)
    assert np.all(motion.commanded <= INTERPOLATOR.upper)
    assert np.all(motion.commanded >= INTERPOLATOR.lower)  # False for NaN too


def test_restart_from_holds_the_measured_pose_not_the_initial_one() -> None:
    motion = _controller()
    parked = np.array([0.4, -0.3, 0.2, 0.1, -0.5, 0.6])
    motion.restart_from(parked)
    hold = TickCommand(Cmd.HOLD, Owner.FALLBACK, parked, None, None)
    command = motion.command(hold, _sensed(0, parked))
    assert np.allclose(command.q, parked)


@pytest.mark.parametrize(("moving", "held"), [(150, 400), (179, 1), (60, 7), (300, 30)],
                         ids=["long-hold", "one-tick", "accelerating", "braking"])
def test_a_paused_planner_move_resumes_within_the_limits(moving: int, held: int) -> None:
    """Interrupted at any point of its profile, for any time, the move resumes without a step
    in velocity or acceleration: the discrete jerk stays within the owners' jerk limits."""
    q0, q1 = np.zeros(6), np.array([0.9, 0.0, 0.0, 0.0, 0.0, 0.0])
    runner = _Runner(PlannedMove(plan_joint_move(q0, q1, PLANNER)))
    motion = _controller(runner)
    t, positions = 0, []

    def run(tick: TickCommand, n: int) -> None:
        nonlocal t
        for _ in range(n):
            positions.append(np.array(motion.command(tick, _sensed(t, motion.commanded)).q))
            t += PERIOD_NS

    run(PLANNER_TICK, moving)
    hold = TickCommand(Cmd.HOLD, Owner.FALLBACK, positions[-1].copy(), None, None)
    run(hold, held)  # a fallback takes the tick, latched where the arm was
    run(PLANNER_TICK, 2500)  # recovery: the planner owns the tick again
    dt = PERIOD_NS * 1e-9
    jerk = np.abs(np.diff(np.array(positions), n=3, axis=0)).max() / dt**3
    assert jerk <= max(INTERPOLATOR.jerk.max(), PLANNER.jerk.max()) * 1.05
    acceleration = np.abs(np.diff(np.array(positions), n=2, axis=0)).max() / dt**2
    assert acceleration <= INTERPOLATOR.acceleration.max() * 1.05
    assert np.allclose(positions[-1], q1, atol=1e-6)  # and the move still reaches its target


class _Recording:
    """The managed driver, with every command it is given kept for the test to read."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.written: list[Command] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    async def write(self, command: Command) -> Any:
        self.written.append(command)
        return await self.inner.write(command)


class _BrokenMotion:
    commanded = np.zeros(6)

    def command(self, tick: TickCommand, s: Sensed) -> Command:
        raise RuntimeError("motion layer bug")


class _BrokenRunner:
    gripper = 0.0
    done = False

    def update(self, *args: Any) -> None:
        raise RuntimeError("cycle runner bug")


def _context(tmp: Path):  # type: ignore[no-untyped-def]
    return open_run(manifest("sim-ur5e.toml", 1, ClockKind.VIRTUAL), VirtualClock(), tmp, None)


@pytest.mark.parametrize("broken", ["motion", "runner"])
def test_a_software_fault_in_the_tick_stops_the_device_before_the_error_ends_the_run(
        tmp_path: Path, broken: str) -> None:
    context = _context(tmp_path)
    controller = context.cell.controller

    async def scenario() -> None:
        await bring_up(context)
        controller.start()
        recording = _Recording(controller.driver)
        controller.driver = recording  # type: ignore[assignment]
        if broken == "motion":
            controller.motion = _BrokenMotion()  # type: ignore[assignment]
        else:
            controller.runner = _BrokenRunner()  # type: ignore[assignment]
        with pytest.raises(RuntimeError, match=f"{broken} .*bug"):
            await controller.tick()
        assert [c.kind for c in recording.written] == [CommandKind.STOP]

    try:
        asyncio.run(scenario())
    finally:
        context.cell.world.close()
        context.files.close()


def test_bring_up_holds_a_device_parked_away_from_home(tmp_path: Path) -> None:
    context = _context(tmp_path)
    cell = context.cell
    parked = np.array(cell.layout.home_q) + np.array([0.3, -0.2, 0.25, 0.1, -0.15, 0.2])
    cell.world.plant.reset(parked)  # type: ignore[attr-defined]

    async def scenario() -> None:
        await bring_up(context)
        assert np.allclose(cell.controller.motion.commanded, parked, atol=1e-3)
        cell.controller.start()
        await cell.controller.tick()

    try:
        asyncio.run(scenario())
    finally:
        cell.world.close()
        context.files.close()
    assert np.abs(cell.controller.motion.commanded - parked).max() < 0.01


def test_a_dead_policy_link_task_is_a_lost_link_for_the_core(tmp_path: Path) -> None:
    from kernel.cell.build import offer_for
    from kernel.cell.live import task_failed
    from kernel.core.events import HandshakeEvent

    context = _context(tmp_path)
    gateway = context.cell.gateway
    try:
        gateway.feed(HandshakeEvent(t=gateway.now_ns(), offer=offer_for(context.manifest)))
        assert context.cell.core.state.session is not None
        failures: list[str] = []
        task_failed(context, failures, "policy-link", ConnectionResetError("peer vanished"))
        state = context.cell.core.state
        assert failures == ["policy-link: ConnectionResetError"]
        assert state.session is None and str(state.fallback.mode) == "DEGRADED"
    finally:
        context.cell.world.close()
        context.files.close()
