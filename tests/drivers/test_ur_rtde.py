"""URRTDEDriver commanding a healthy arm: real ur_rtde, real TCP, the emulated controller.

The tests share one emulator and one active driver (closing a driver costs about a second:
ur_rtde's destructors sleep); each starts from a held, fault-free arm. The last test streams
to an emulator backed by the MuJoCo plant. Faults and bad input are in test_ur_faults.py, link
loss (which can crash a client) in test_ur_link_loss.py.
"""

from __future__ import annotations

import asyncio
import importlib.util
import math
from collections.abc import AsyncIterator, Iterator

import numpy as np
import pytest
import pytest_asyncio

from assurance.reasons import ReasonCode
from drivers.base import Command, CommandKind, ControlConfig, DriverState
from drivers.lifecycle import ManagedDriver
from drivers.ur_rtde.driver import URRTDEDriver
from drivers.ur_rtde.settings import URSettings
from stubs.ur_controller.launch import EmulatedController
from tests.drivers.support import active

PERIOD_S = 0.002
LIMIT = 3.0
CONTROL = ControlConfig(dof=6, period_ns=int(PERIOD_S * 1e9), q_lower=(-LIMIT,) * 6,
                        q_upper=(LIMIT,) * 6, v_max=(1.0,) * 6)


@pytest.fixture(scope="module")
def emulator() -> Iterator[EmulatedController]:
    with EmulatedController() as controller:
        yield controller


PATIENT_WATCHDOG = 2500
"""Control periods (5 s): these tests pause between writes (up to 2 s while the arm settles),
which the kernel never does; the watchdog's own tests are in test_ur_watchdog.py."""


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def shared_arm(emulator: EmulatedController) -> AsyncIterator[ManagedDriver]:
    emulator.clear()
    settings = URSettings(host=emulator.host, watchdog_periods=PATIENT_WATCHDOG)
    async with active(URRTDEDriver(settings, name="ur5e"), CONTROL) as arm:
        yield arm


@pytest_asyncio.fixture(loop_scope="module")
async def arm(shared_arm: ManagedDriver, emulator: EmulatedController
              ) -> AsyncIterator[ManagedDriver]:
    """The shared active driver, held still and fault-free at the start of every test."""
    assert shared_arm.state is DriverState.ACTIVE, shared_arm.fault_detail
    emulator.clear()
    # HOLD holds the last setpoint (a far one a test left would be followed on): command
    # where the arm is first.
    here = (await shared_arm.read()).q
    await shared_arm.write(Command(kind=CommandKind.POSITION, q=here))
    await shared_arm.hold()
    await _until_still(shared_arm)
    yield shared_arm


async def _until_still(driver: ManagedDriver, timeout_s: float = 2.0) -> None:
    """Wait until the held arm has stopped moving (on a loaded machine this can take a while)."""
    previous = np.array((await driver.read()).q)
    for _ in range(int(timeout_s / 0.02)):
        await asyncio.sleep(0.02)
        current = np.array((await driver.read()).q)
        if np.abs(current - previous).max() < 1e-5:
            return
        previous = current


on_shared_loop = pytest.mark.asyncio(loop_scope="module")


async def stream(driver: ManagedDriver, command: Command, seconds: float) -> None:
    for _ in range(int(seconds / PERIOD_S)):
        await driver.write(command)
        await asyncio.sleep(PERIOD_S)


@on_shared_loop
async def test_servo_streaming_moves_the_arm_and_reports_what_was_applied(
    arm: ManagedDriver,
) -> None:
    start = np.array((await arm.read()).q)
    target = start + np.array([0.2, -0.1, 0.05, 0.0, 0.0, 0.1])
    await stream(arm, Command(kind=CommandKind.POSITION, q=tuple(target)), 0.5)
    reached = np.array((await arm.read()).q)
    assert np.abs(reached - target).max() < 0.01
    assert arm.stats["write"].count >= 100


@on_shared_loop
async def test_position_beyond_the_limits_is_clipped_and_reported(arm: ManagedDriver) -> None:
    q = list((await arm.read()).q)
    q[0] = LIMIT + 1.0
    applied = await arm.write(Command(kind=CommandKind.POSITION, q=tuple(q)))
    assert applied.accepted
    assert applied.q[0] == LIMIT


@on_shared_loop
async def test_non_finite_setpoint_is_refused_and_moves_nothing(arm: ManagedDriver) -> None:
    before = np.array((await arm.read()).q)
    bad = (math.nan, *before[1:].tolist())
    applied = await arm.write(Command(kind=CommandKind.POSITION, q=bad))
    assert not applied.accepted
    assert applied.reason is ReasonCode.NONFINITE
    await asyncio.sleep(0.1)
    assert np.abs(np.array((await arm.read()).q) - before).max() < 1e-3  # NaN would fail too
    assert arm.state is DriverState.ACTIVE


@on_shared_loop
async def test_velocity_then_stop(arm: ManagedDriver) -> None:
    start = (await arm.read()).q[0]
    await stream(arm, Command(kind=CommandKind.VELOCITY, qd=(0.5, 0, 0, 0, 0, 0)), 0.3)
    moving = await arm.read()
    assert moving.qd[0] == pytest.approx(0.5, abs=1e-6)
    assert moving.q[0] - start > 0.08
    stopped = await arm.write(Command(kind=CommandKind.STOP))
    assert stopped.accepted and stopped.kind is CommandKind.STOP
    await asyncio.sleep(0.05)
    assert max(abs(v) for v in (await arm.read()).qd) < 1e-6


@on_shared_loop
async def test_hold_servos_to_the_last_setpoint(arm: ManagedDriver) -> None:
    q = np.array((await arm.read()).q)
    await stream(arm, Command(kind=CommandKind.POSITION, q=tuple(q + 0.3)), 0.05)
    held = await arm.hold()
    assert held.accepted and held.kind is CommandKind.HOLD
    assert np.array(held.q) == pytest.approx(q + 0.3)  # not a reading: it may be glitched
    await asyncio.sleep(0.2)
    assert np.abs(np.array((await arm.read()).q) - np.array(held.q)).max() < 0.01


@on_shared_loop
async def test_speed_scaling_is_reported(arm: ManagedDriver, emulator: EmulatedController
                                         ) -> None:
    assert (await arm.read()).speed_scaling == pytest.approx(1.0)
    emulator.inject("speed_scaling", value=0.3)
    await asyncio.sleep(0.05)
    assert (await arm.read()).speed_scaling == pytest.approx(0.3)


MUJOCO_MISSING = importlib.util.find_spec("stubs.plant.mujoco_plant") is None


@pytest.mark.skipif(MUJOCO_MISSING, reason="stubs/plant/mujoco_plant.py (MujocoPlant) does not "
                    "exist yet; the emulator's --plant mujoco needs it")
async def test_servo_streaming_against_the_mujoco_plant() -> None:
    with EmulatedController(plant="mujoco") as mujoco:
        driver = ManagedDriver(URRTDEDriver(URSettings(host=mujoco.host)))
        try:
            await driver.configure(CONTROL)
            await driver.activate()
            start = np.array((await driver.read()).q)
            target = start + np.array([0.1, 0, 0, 0, 0, 0])
            await stream(driver, Command(kind=CommandKind.POSITION, q=tuple(target)), 1.0)
            assert abs((await driver.read()).q[0] - target[0]) < 0.05
        finally:
            await driver.aclose()
