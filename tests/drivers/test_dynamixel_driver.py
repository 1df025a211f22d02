"""The Dynamixel driver against the bus emulator: bad setup, retries, faults, motion, calibration.

Real dynamixel_sdk over a real pty to ``python -m stubs.dynamixel_bus``; nothing is mocked.
One emulator serves the module, ``clear`` after every test. To look at the servos independently
of the driver, tests open the port with the bare SDK while no driver holds it.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Iterator
from typing import Any

import pytest
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from assurance.reasons import ReasonCode
from drivers.base import (
    Command,
    CommandKind,
    ControlConfig,
    DeviceFault,
    DriverInitError,
    DriverIOError,
    DriverState,
    DriverTimeout,
)
from drivers.dynamixel.driver import DynamixelDriver
from drivers.dynamixel.settings import DynamixelSettings
from drivers.dynamixel.units import RAD_PER_TICK
from drivers.lifecycle import ManagedDriver
from stubs.dynamixel_bus.launch import WIDE_TIMING, BusEmulator
from tests.drivers.support import active

IDS = (1, 2, 3, 4, 5, 6)
PERIOD_S = 0.004
CONTROL = ControlConfig(dof=6, period_ns=int(PERIOD_S * 1e9), q_lower=(-3.0,) * 6,
                        q_upper=(3.0,) * 6, v_max=(3.0,) * 6)


@pytest.fixture(scope="module")
def bus() -> Iterator[BusEmulator]:
    with BusEmulator("--ids", ",".join(map(str, IDS))) as emulator:
        yield emulator


@pytest.fixture(autouse=True)
def clear_faults(bus: BusEmulator) -> Iterator[None]:
    yield
    bus.inject("clear")


PATIENT_WATCHDOG = {"watchdog_periods": 500}
"""2 s at 4 ms: these tests pause between packets, which the kernel never does; the Bus
Watchdog's own tests are in test_dynamixel_watchdog.py."""


def settings(port: str, **overrides: Any) -> DynamixelSettings:
    return DynamixelSettings(port=port, **{**WIDE_TIMING, **PATIENT_WATCHDOG, **overrides})


def active_driver(port: str, **overrides: Any) -> contextlib.AbstractAsyncContextManager:
    return active(DynamixelDriver(settings(port, **overrides)), CONTROL)


@contextlib.contextmanager
def bare_sdk(port_path: str) -> Iterator[tuple[PortHandler, PacketHandler]]:
    """The plain SDK on the emulator's port, for checks that must not trust the driver."""
    port = PortHandler(port_path)
    port.openPort()
    try:
        yield port, PacketHandler(2.0)
    finally:
        port.closePort()


async def stream(driver: ManagedDriver, q: tuple[float, ...], seconds: float) -> None:
    for _ in range(int(seconds / PERIOD_S)):
        applied = await driver.write(Command(kind=CommandKind.POSITION, q=q))
        assert applied.accepted, applied
        await asyncio.sleep(PERIOD_S)


# ---------------------------------------------------------------------------- bad setup


async def test_missing_servo_at_connect_names_id_and_port(bus: BusEmulator) -> None:
    ids = (*IDS, 7)
    driver = DynamixelDriver(settings(bus.port, ids=ids, offsets_rad=(0.0,) * 7,
                                      directions=(1,) * 7))
    with pytest.raises(DriverInitError) as caught:
        await driver.connect()
    await driver.aclose()
    message = str(caught.value)
    assert "servo id 7 does not answer" in message
    assert bus.port in message and "1, 2, 3, 4, 5, 6 do" in message


async def test_wrong_port_path_is_init_error(tmp_path: Any) -> None:
    missing = str(tmp_path / "ttyUSB-not-here")
    driver = DynamixelDriver(settings(missing))
    with pytest.raises(DriverInitError, match=r"cannot open serial port .*ttyUSB-not-here.*`port`"):
        await driver.connect()
    await driver.aclose()


def test_baud_rate_outside_the_servos_rates_is_refused_in_the_settings(bus: BusEmulator) -> None:
    # Refused before any port is opened; the driver's own check at connect stays as a backstop.
    with pytest.raises(ValueError, match=r"baud: 123456 is not a rate"):
        settings(bus.port, baud=123_456)


async def test_baud_rate_the_bus_does_not_use_is_init_error(bus: BusEmulator) -> None:
    # 57600 is a valid SDK rate, but the servos listen at 1 Mbps: nobody answers.
    driver = DynamixelDriver(settings(bus.port, baud=57_600, latency_budget_ms=10.0))
    with pytest.raises(DriverInitError) as caught:
        await driver.connect()
    assert "no servo answers" in str(caught.value)
    assert "57600 baud" in str(caught.value) and "Baud Rate (address 8)" in str(caught.value)


async def test_second_driver_on_the_same_port_is_init_error(bus: BusEmulator) -> None:
    async with active_driver(bus.port):
        second = DynamixelDriver(settings(bus.port), name="intruder")
        with pytest.raises(DriverInitError, match="already in use"):
            await second.connect()


async def test_dof_mismatch_is_init_error(bus: BusEmulator) -> None:
    driver = ManagedDriver(DynamixelDriver(settings(bus.port)))
    wrong = ControlConfig(dof=5, period_ns=CONTROL.period_ns, q_lower=(-3.0,) * 5,
                          q_upper=(3.0,) * 5, v_max=(3.0,) * 5)
    try:
        with pytest.raises(DriverInitError, match="5 joints but `ids` lists 6 servos"):
            await driver.configure(wrong)
    finally:
        await driver.aclose()


async def test_configure_puts_servos_in_position_mode(bus: BusEmulator) -> None:
    with bare_sdk(bus.port) as (port, sdk):
        assert sdk.write1ByteTxRx(port, 3, 11, 1) == (COMM_SUCCESS, 0)  # velocity mode
    driver = ManagedDriver(DynamixelDriver(settings(bus.port)))
    await driver.configure(CONTROL)
    await driver.aclose()
    with bare_sdk(bus.port) as (port, sdk):
        assert [sdk.read1ByteTxRx(port, i, 11)[0] for i in IDS] == [3] * 6


# ---------------------------------------------------------------------------- motion


async def test_sync_write_moves_the_plant_and_aclose_releases_torque(bus: BusEmulator) -> None:
    async with active_driver(bus.port) as driver:
        start = (await driver.read()).q
        target = (start[0] + 0.3, *start[1:5], start[5] - 0.2)
        await stream(driver, target, 0.5)
        reached = (await driver.read()).q
    assert max(abs(a - b) for a, b in zip(reached, target, strict=True)) < 0.01
    with bare_sdk(bus.port) as (port, sdk):
        assert [sdk.read1ByteTxRx(port, i, 64)[0] for i in IDS] == [0] * 6  # torque off


async def test_calibration_offsets_and_directions_reach_the_servos(bus: BusEmulator) -> None:
    offsets = (0.1, -0.2, 0.0, 0.3, 0.0, -0.1)
    directions = (1, -1, 1, -1, 1, -1)
    target = (0.4, 0.5, -0.3, 0.2, 0.1, -0.6)
    async with active_driver(bus.port, offsets_rad=offsets, directions=directions) as driver:
        await stream(driver, target, 0.6)
        reported = (await driver.read()).q
    assert max(abs(a - b) for a, b in zip(reported, target, strict=True)) < 0.01
    with bare_sdk(bus.port) as (port, sdk):
        ticks = [sdk.read4ByteTxRx(port, i, 132)[0] for i in IDS]
    for tick, q, offset, direction in zip(ticks, target, offsets, directions, strict=True):
        shaft = (tick - 2048) * RAD_PER_TICK
        assert math.isclose(shaft, direction * q + offset, abs_tol=0.01), (tick, q)


async def test_velocity_and_position_keep_their_sign(bus: BusEmulator) -> None:
    async with active_driver(bus.port, directions=(1, -1, 1, 1, 1, 1)) as driver:
        here = (await driver.read()).q
        target = (here[0] - 0.5, here[1] - 0.5, *here[2:])
        await driver.write(Command(kind=CommandKind.POSITION, q=target))
        await asyncio.sleep(0.05)
        moving = await driver.read()
    # Both joints head for lower angles; joint 1's servo turns the other way round.
    assert -3.3 < moving.qd[0] < -0.5 and -3.3 < moving.qd[1] < -0.5
    assert moving.q[0] < here[0] - 0.05


async def test_position_is_clipped_to_the_joint_limits(bus: BusEmulator) -> None:
    async with active_driver(bus.port) as driver:
        q = (await driver.read()).q
        applied = await driver.write(Command(kind=CommandKind.POSITION, q=(5.0, *q[1:])))
    assert applied.accepted and applied.q[0] == 3.0


async def test_bad_commands_are_refused_and_move_nothing(bus: BusEmulator) -> None:
    async with active_driver(bus.port) as driver:
        q = (await driver.read()).q
        refusals = [
            await driver.write(Command(kind=CommandKind.VELOCITY, qd=(0.5,) * 6)),
            await driver.write(Command(kind=CommandKind.POSITION, q=q[:5])),
            await driver.write(Command(kind=CommandKind.POSITION, q=(math.nan, *q[1:]))),
        ]
        await asyncio.sleep(0.2)
        after = (await driver.read()).q
        assert driver.state is DriverState.ACTIVE
    assert [r.reason for r in refusals] == [ReasonCode.CONTROLLER_MODE_MISMATCH,
                                            ReasonCode.MALFORMED, ReasonCode.NONFINITE]
    assert not any(r.accepted for r in refusals)
    assert max(abs(a - b) for a, b in zip(after, q, strict=True)) < 0.005


async def test_stop_holds_where_the_arm_is(bus: BusEmulator) -> None:
    async with active_driver(bus.port) as driver:
        here = (await driver.read()).q
        await driver.write(Command(kind=CommandKind.POSITION, q=(here[0] + 1.0, *here[1:])))
        await asyncio.sleep(0.05)  # moving
        stopped = await driver.write(Command(kind=CommandKind.STOP))
        await asyncio.sleep(0.2)
        after = (await driver.read()).q
    assert stopped.accepted and stopped.kind is CommandKind.STOP
    assert abs(after[0] - stopped.q[0]) < 0.01 and after[0] < here[0] + 0.9


# ---------------------------------------------------------------------------- faults


async def test_crc_corruption_is_retried_and_recovers(bus: BusEmulator) -> None:
    async with active_driver(bus.port) as driver:
        dynamixel = driver.driver
        assert isinstance(dynamixel, DynamixelDriver) and dynamixel.bus is not None
        before = dynamixel.bus.counters.corrupt
        bus.inject("crc", count=2)  # two bad replies: within the two retries
        sample = await driver.read()
        assert driver.state is DriverState.ACTIVE and len(sample.q) == 6
        assert dynamixel.bus.counters.corrupt - before == 2
        assert dynamixel.bus.counters.retries >= 2


async def test_crc_corruption_beyond_the_retries_is_link_lost(bus: BusEmulator) -> None:
    async with active_driver(bus.port) as driver:
        bus.inject("crc", count=3)  # one more than the retries allow; pings afterwards are clean
        with pytest.raises(DriverIOError):
            await driver.read()
        assert driver.fault is ReasonCode.LINK_LOST
        assert "every servo answers ping" in driver.fault_detail


async def test_silent_servo_is_link_lost_naming_the_id(bus: BusEmulator) -> None:
    async with active_driver(bus.port) as driver:
        await driver.read()
        bus.inject("silent", id=3)
        with pytest.raises(DriverIOError):
            await driver.read()
        assert driver.state is DriverState.FAULT and driver.fault is ReasonCode.LINK_LOST
        assert f"servo id 3 on {bus.port} stopped answering" in driver.fault_detail


@pytest.mark.parametrize(("bit", "name"), [("overload", "overload"),
                                           ("motor_encoder", "motor encoder error"),
                                           ("electrical_shock", "electrical shock")])
async def test_hardware_error_is_controller_fault_naming_the_bit(
    bus: BusEmulator, bit: str, name: str
) -> None:
    async with active_driver(bus.port) as driver:
        bus.inject("hardware_error", id=5, bit=bit)
        with pytest.raises(DeviceFault):
            await driver.read()
        assert driver.fault is ReasonCode.CONTROLLER_FAULT
        assert f"servo id 5: {name}" in driver.fault_detail


async def test_hardware_error_before_connect_refuses_to_start(bus: BusEmulator) -> None:
    bus.inject("hardware_error", id=1, bit="overheating")
    driver = ManagedDriver(DynamixelDriver(settings(bus.port)))
    try:
        with pytest.raises(DeviceFault, match="servo id 1: overheating"):
            await driver.configure(CONTROL)
        assert driver.fault is ReasonCode.CONTROLLER_FAULT
    finally:
        await driver.aclose()


async def test_missed_deadline_is_watchdog_and_aclose_still_releases(bus: BusEmulator) -> None:
    # The deadline is shorter than one packet timeout: the call is abandoned mid-SDK.
    driver = ManagedDriver(DynamixelDriver(settings(bus.port, call_timeout_s=0.05)))
    await driver.configure(CONTROL)
    try:
        bus.inject("silent", id=2)
        with pytest.raises(DriverTimeout):
            await driver.read()
        assert driver.fault is ReasonCode.WATCHDOG
    finally:
        await driver.aclose()
    bus.inject("clear")
    async with active_driver(bus.port) as again:  # the port lock was released
        assert len((await again.read()).q) == 6


# ---------------------------------------------------------------------------- other buses

THREE_SERVOS = {"ids": (1, 2, 3), "offsets_rad": (0.0,) * 3, "directions": (1,) * 3}
THREE_JOINTS = ControlConfig(dof=3, period_ns=CONTROL.period_ns, q_lower=(-3.0,) * 3,
                             q_upper=(3.0,) * 3, v_max=(3.0,) * 3)


async def test_servo_that_is_not_x_series_is_init_error() -> None:
    with BusEmulator("--ids", "1,2,3", "--model", "12") as ax_bus:  # 12: an AX-12A
        driver = DynamixelDriver(settings(ax_bus.port, **THREE_SERVOS))
        with pytest.raises(DriverInitError, match=r"id 1 is model 12, .*: not an X-series servo"):
            await driver.connect()


async def test_adapter_gone_mid_run_is_link_lost() -> None:
    with BusEmulator("--ids", "1,2,3") as doomed:
        driver = ManagedDriver(DynamixelDriver(settings(doomed.port, **THREE_SERVOS)))
        await driver.configure(THREE_JOINTS)
        await driver.activate()
        await driver.read()
        doomed.stop()  # the pty goes away under the open port, as an unplugged USB adapter
        try:
            with pytest.raises(DriverIOError):
                await driver.read()
            assert driver.fault is ReasonCode.LINK_LOST
            assert f"serial port {doomed.port} failed" in driver.fault_detail
        finally:
            await driver.aclose()
        assert driver.state is DriverState.CLOSED


# ---------------------------------------------------------------------------- old firmware


async def test_falls_back_to_sync_read_without_fast_sync_read() -> None:
    with BusEmulator("--ids", "1,2,3", "--no-fast-sync-read") as old_bus:
        # Each fast-read probe waits a full packet timeout: keep the budget short here.
        three = {**THREE_SERVOS, "latency_budget_ms": 30.0}
        driver = ManagedDriver(DynamixelDriver(settings(old_bus.port, **three)))
        try:
            await driver.configure(THREE_JOINTS)
            await driver.activate()
            dynamixel = driver.driver
            assert isinstance(dynamixel, DynamixelDriver) and dynamixel.bus is not None
            assert not dynamixel.bus.uses_fast_sync_read
            start = (await driver.read()).q
            target = (start[0] - 0.2, start[1], start[2])
            await stream(driver, target, 0.4)
            assert abs((await driver.read()).q[0] - target[0]) < 0.01
            old_bus.inject("silent", id=2)  # sync read knows which reply was missing
            with pytest.raises(DriverIOError, match=r"servo id 2 on .* stopped answering"):
                await driver.read()
        finally:
            await driver.aclose()
