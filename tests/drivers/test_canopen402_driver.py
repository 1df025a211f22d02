"""The CiA 402 driver against emulated drives, through the real canopen and python-can.

Each test gets its own emulated arm on a ``virtual`` bus channel nobody else uses; the
conformance suite (tests/conformance) covers the same driver over ``udp_multicast`` too.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from assurance.reasons import ReasonCode
from drivers.base import (
    Command,
    CommandKind,
    DeviceFault,
    DriverError,
    DriverInitError,
    DriverIOError,
    DriverState,
)
from drivers.canopen402 import CiA402Settings
from drivers.canopen402.driver import CiA402Driver
from drivers.canopen402.tables import DriveState
from drivers.lifecycle import ManagedDriver
from stubs.cia402_drive import DriveEmulator
from stubs.cia402_drive.profile import Mode, PowerState
from stubs.plant.base import Plant
from tests.drivers import cia402_testbed as arm

PERIOD_S = arm.TEST_PERIOD_NS * 1e-9


@dataclass
class Arm:
    emulator: DriveEmulator
    channel: str

    def settings(self, **overrides: Any) -> CiA402Settings:
        return arm.driver_settings("virtual", self.channel, **overrides)

    def states(self) -> set[PowerState]:
        return {drive.state for drive in self.emulator.drives.values()}

    def plant_q(self) -> np.ndarray:
        with self.emulator.lock:
            return np.array(self.emulator.plant.state().q)


def _start_arm(plant: Plant | None = None) -> Iterator[Arm]:
    channel = arm.unique_virtual_channel()
    emulator = DriveEmulator(arm.emulator_config("virtual", channel), plant).start()
    try:
        yield Arm(emulator, channel)
    finally:
        emulator.stop()


@pytest.fixture
def bus() -> Iterator[Arm]:
    yield from _start_arm()


async def _configured(settings: CiA402Settings) -> ManagedDriver:
    driver = ManagedDriver(CiA402Driver(settings))
    try:
        await driver.configure(arm.control())
    except BaseException:
        await driver.aclose()
        raise
    return driver


async def _active(settings: CiA402Settings) -> ManagedDriver:
    driver = await _configured(settings)
    await driver.activate()
    return driver


async def _stream(driver: ManagedDriver, q: np.ndarray, seconds: float) -> None:
    for _ in range(max(1, round(seconds / PERIOD_S))):
        applied = await driver.write(Command(kind=CommandKind.POSITION, q=tuple(q.tolist())))
        assert applied.accepted, applied
        await asyncio.sleep(PERIOD_S)


async def _until_error(driver: ManagedDriver, timeout_s: float = 3.0) -> DriverError:
    """Run the control loop (read, write what was read) until the driver raises."""
    deadline = asyncio.get_running_loop().time() + timeout_s
    while asyncio.get_running_loop().time() < deadline:
        try:
            sample = await driver.read()
            await driver.write(Command(kind=CommandKind.POSITION, q=sample.q))
        except DriverError as error:
            return error
        await asyncio.sleep(PERIOD_S)
    raise AssertionError(f"no driver error within {timeout_s} s")


async def test_402_walk_to_operation_enabled_and_back(bus: Arm) -> None:
    driver = await _configured(bus.settings())
    try:
        assert bus.states() == {PowerState.SWITCH_ON_DISABLED}
        assert {d.mode for d in bus.emulator.drives.values()} == {
            Mode.CYCLIC_SYNCHRONOUS_POSITION}
        await driver.activate()
        assert bus.states() == {PowerState.OPERATION_ENABLED}
        assert set(driver.driver.drive_states().values()) == {DriveState.OPERATION_ENABLED}
        await driver.deactivate()
        assert bus.states() == {PowerState.SWITCH_ON_DISABLED}
        assert set(driver.driver.drive_states().values()) == {DriveState.SWITCH_ON_DISABLED}
    finally:
        await driver.aclose()
    assert {d.node.nmt.state for d in bus.emulator.drives.values()} == {"PRE-OPERATIONAL"}


async def test_csp_targets_move_every_joint_of_the_plant(bus: Arm) -> None:
    driver = await _active(bus.settings())
    try:
        start = np.array((await driver.read()).q)
        assert np.allclose(start, bus.plant_q(), atol=1e-5)  # offsets and signs undone
        target = start + np.array([0.10, -0.10, 0.05, -0.05, 0.10, -0.10])
        for fraction in np.linspace(0.0, 1.0, 60):  # a ramp, as a trajectory would send
            await _stream(driver, start + fraction * (target - start), PERIOD_S)
        await _stream(driver, target, 0.3)
        assert np.allclose(bus.plant_q(), target, atol=0.01)
        assert np.allclose((await driver.read()).q, target, atol=0.01)
    finally:
        await driver.aclose()


@pytest.mark.parametrize("resume", [CommandKind.POSITION, CommandKind.HOLD])
async def test_quick_stop_holds_until_the_next_command_resumes_from_where_it_stopped(
        bus: Arm, resume: CommandKind) -> None:
    """After a quick stop the drives stay in QUICK STOP ACTIVE, at rest short of the goal;
    the next setpoint (the core's first after an accepted recovery) or hold enables them again
    with their targets where the stop left them, so nothing jumps toward the old goal.
    Before, a setpoint there was refused (CONTROLLER_REJECT) until a HOLD came, which the core
    never sends after a recovery: each recovery ended in another CONTROLLER_STOP."""
    driver = await _active(bus.settings())
    try:
        start = np.array((await driver.read()).q)
        goal = start + np.array([0.5, 0, 0, 0, 0, 0])
        for fraction in np.linspace(0.0, 0.4, 20):  # under way to the goal, then stop
            await _stream(driver, start + fraction * (goal - start), PERIOD_S)
        stopped = await driver.write(Command(kind=CommandKind.STOP))
        assert stopped.accepted
        await asyncio.sleep(0.15)
        assert bus.states() == {PowerState.QUICK_STOP_ACTIVE}
        before = np.array((await driver.read()).q)
        await asyncio.sleep(0.2)
        assert np.abs(np.array((await driver.read()).q) - before).max() < 1e-3
        assert abs(before[0] - goal[0]) > 0.2  # it stopped short of the goal
        resumed = await driver.write(Command(kind=resume, q=tuple(before.tolist()) if (
            resume is CommandKind.POSITION) else ()))
        assert resumed.accepted, resumed
        assert bus.states() == {PowerState.OPERATION_ENABLED}
        for _ in range(round(0.1 / PERIOD_S)):  # held where it stopped, not off to the goal
            await driver.write(Command(kind=CommandKind.HOLD))
            await asyncio.sleep(PERIOD_S)
        assert np.abs(bus.plant_q() - before).max() < 1e-3
        await _stream(driver, before + 0.05, 0.3)
        assert abs(bus.plant_q()[0] - (before[0] + 0.05)) < 0.01
    finally:
        await driver.aclose()


async def test_emcy_is_a_controller_fault_reset_only_on_a_reconnect_that_allows_it(
    bus: Arm,
) -> None:
    driver = await _active(bus.settings())
    try:
        bus.emulator.inject("emcy", node=4, code=0x4310)
        error = await _until_error(driver)
        assert isinstance(error, DeviceFault)
        assert error.reason is ReasonCode.CONTROLLER_FAULT
        assert "node 4" in str(error) and "0x4310" in str(error)
        assert driver.state is DriverState.FAULT
    finally:
        await driver.aclose()
    assert bus.emulator.drive(4).state is PowerState.FAULT  # nothing reset it on the way out
    with pytest.raises(DriverInitError, match=r"node 4 is in FAULT.*0x4310"):
        await _configured(bus.settings())
    resetting = await _active(bus.settings(reset_faults_on_connect=True))
    try:
        assert bus.emulator.drive(4).error_code == 0
        start = np.array((await resetting.read()).q)
        await _stream(resetting, start + np.array([0, 0, 0, 0.05, 0, 0]), 0.3)
        assert abs(bus.plant_q()[3] - (start[3] + 0.05)) < 0.01
    finally:
        await resetting.aclose()


async def test_drive_in_fault_at_start_is_refused_with_its_error(bus: Arm) -> None:
    bus.emulator.inject("emcy", node=2, code=0x3210, register=0x04)
    with pytest.raises(DriverInitError) as refused:
        await _configured(bus.settings())
    message = str(refused.value)
    assert "node 2 is in FAULT" in message
    assert "0x3210" in message and "error register 0x05" in message
    assert "reset_faults_on_connect" in message
    driver = await _configured(bus.settings(reset_faults_on_connect=True))
    try:
        assert bus.emulator.drive(2).state is PowerState.SWITCH_ON_DISABLED
    finally:
        await driver.aclose()


async def test_missing_node_at_connect_names_node_interface_and_channel(bus: Arm) -> None:
    settings = bus.settings(node_ids=(1, 2, 3, 4, 5, 9), sdo_timeout_s=0.2)
    with pytest.raises(DriverInitError) as missing:
        await _configured(settings)
    message = str(missing.value)
    assert "node 9 does not answer" in message
    assert "'virtual'" in message and bus.channel in message


async def test_unknown_interface_is_an_init_error() -> None:
    settings = arm.driver_settings("no-such-can", "can0")
    with pytest.raises(DriverInitError, match="unknown CAN interface 'no-such-can'"):
        await _configured(settings)


async def test_drive_that_never_confirms_csp_is_refused(bus: Arm) -> None:
    bus.emulator.inject("ignore_mode", node=5)
    with pytest.raises(DriverInitError, match="node 5 did not confirm CYCLIC SYNCHRONOUS"):
        await _configured(bus.settings(state_timeout_s=0.3))


async def test_heartbeat_loss_is_link_lost_naming_the_node(bus: Arm) -> None:
    driver = await _active(bus.settings(heartbeat_period_ms=20, heartbeat_timeout_ms=100))
    try:
        bus.emulator.inject("heartbeat_stop", node=2)
        error = await _until_error(driver)
        assert isinstance(error, DriverIOError)
        assert error.reason is ReasonCode.LINK_LOST
        assert "node 2 heartbeat lost" in str(error)
    finally:
        await driver.aclose()


async def test_bad_commands_are_refused_without_moving(bus: Arm) -> None:
    driver = await _active(bus.settings())
    try:
        q = (await driver.read()).q
        cases = {
            ReasonCode.NONFINITE: Command(kind=CommandKind.POSITION, q=(math.nan, *q[1:])),
            ReasonCode.MALFORMED: Command(kind=CommandKind.POSITION, q=q[:3]),
            ReasonCode.CONTROLLER_MODE_MISMATCH: Command(kind=CommandKind.VELOCITY,
                                                         qd=(0.1,) * 6),
        }
        for reason, command in cases.items():
            applied = await driver.write(command)
            assert (applied.accepted, applied.reason) == (False, reason)
        await asyncio.sleep(0.1)
        assert np.allclose(bus.plant_q(), q, atol=1e-4)
    finally:
        await driver.aclose()


async def test_position_beyond_the_limits_is_clipped_and_reported(bus: Arm) -> None:
    driver = await _active(bus.settings())
    try:
        q = list((await driver.read()).q)
        q[2] = 100.0
        applied = await driver.write(Command(kind=CommandKind.POSITION, q=tuple(q)))
        assert applied.accepted
        assert abs(applied.q[2] - arm.control().q_upper[2]) < 1e-6
    finally:
        await driver.aclose()


async def test_closing_an_enabled_driver_quick_stops_the_drives(bus: Arm) -> None:
    driver = await _active(bus.settings())
    await driver.driver.aclose()  # the hook itself, as after a crash of the lifecycle
    await asyncio.sleep(0.05)
    assert bus.states() == {PowerState.QUICK_STOP_ACTIVE}
    assert {d.node.nmt.state for d in bus.emulator.drives.values()} == {"PRE-OPERATIONAL"}
    await driver.aclose()


async def test_an_echo_of_our_own_rpdo_does_not_overwrite_the_setpoint(bus: Arm) -> None:
    """udp_multicast hands a bus its own frames back; an echo of an older RPDO must not
    replace the setpoint (or controlword) the next cycle will send. Fed deterministically here
    through canopen's public ``Network.notify``, as the notifier would."""
    driver = await _active(bus.settings())
    try:
        link = driver.driver.link  # type: ignore[attr-defined]
        rpdo = link.nodes[0].rpdo[1]
        stale = bytes(rpdo.data)
        q = np.array((await driver.read()).q)
        await driver.write(Command(kind=CommandKind.POSITION, q=tuple(q + 0.01)))
        sent = bytes(rpdo.data)
        assert sent != stale
        link.network.notify(rpdo.cob_id, bytearray(stale), 0.0)
        assert bytes(rpdo.data) == sent
    finally:
        await driver.aclose()


async def test_next_sample_answers_the_last_sync(bus: Arm) -> None:
    driver = await _active(bus.settings())
    try:
        cycle = driver.driver.cycle
        assert cycle is not None
        q = np.array((await driver.read()).q) + 0.001
        await driver.write(Command(kind=CommandKind.POSITION, q=tuple(q)))
        sent = cycle.cycle
        await driver.driver.next_sample()
        assert cycle.completed >= sent
        assert len(cycle.latencies_ns) > 0
    finally:
        await driver.aclose()


@pytest.mark.slow  # MuJoCo, the emulator and the driver in one interpreter: see below
async def test_emulator_runs_on_the_mujoco_plant() -> None:
    """The emulator, the MuJoCo plant and the driver share this process's GIL: on the loaded
    2-core test host the emulator's heartbeat thread was once starved for 356 ms while its
    PDOs flowed (the driver's consumer timeout is 250 ms), so it runs once more after a
    failure, as the wall-clock cell tests do (tests/conftest.py)."""
    from stubs.plant.mujoco_plant import MujocoPlant

    plant = MujocoPlant()
    assert plant.dof == len(arm.NODE_IDS), "the emulated arm has one drive per plant joint"
    for mujoco_arm in _start_arm(plant):
        driver = await _active(mujoco_arm.settings())
        try:
            start = np.array((await driver.read()).q)
            await _stream(driver, start + np.array([0.05, 0, 0, 0, 0, 0]), 0.5)
            assert abs(mujoco_arm.plant_q()[0] - (start[0] + 0.05)) < 0.02
        finally:
            await driver.aclose()
