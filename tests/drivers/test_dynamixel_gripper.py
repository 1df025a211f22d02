"""The Dynamixel driver's gripper servo against the bus emulator with the MuJoCo plant behind it.

Real dynamixel_sdk over a real pty to ``python -m stubs.dynamixel_bus --gripper-id 7``; nothing
is mocked. The gripper's servo drives the plant's gripper, whose measured opening comes back as
its Present Position; tests check it independently of the driver with the bare SDK while no
driver holds the port.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Iterator
from typing import Any

import pytest
from dynamixel_sdk import PacketHandler, PortHandler

from assurance.reasons import ReasonCode
from drivers.base import (
    Command,
    CommandKind,
    ControlConfig,
    DeviceFault,
    DriverInitError,
    DriverIOError,
    DriverState,
)
from drivers.dynamixel.driver import DynamixelDriver
from drivers.dynamixel.settings import DynamixelSettings
from drivers.lifecycle import ManagedDriver
from drivers.settings import SettingsError
from stubs.dynamixel_bus.__main__ import parse_args
from stubs.dynamixel_bus.launch import WIDE_TIMING, BusEmulator
from tests.drivers.support import active

IDS = (1, 2, 3, 4, 5, 6)
GRIPPER = 7
OPEN_TICKS, CLOSED_TICKS = 2048, 3072  # the defaults on both sides
PERIOD_S = 0.004
CONTROL = ControlConfig(dof=6, period_ns=int(PERIOD_S * 1e9), q_lower=(-3.0,) * 6,
                        q_upper=(3.0,) * 6, v_max=(3.0,) * 6)
TICK_M = 0.085 / (CLOSED_TICKS - OPEN_TICKS)
"""One tick of the gripper servo in metres of opening."""


@pytest.fixture(scope="module")
def bus() -> Iterator[BusEmulator]:
    args = ("--ids", ",".join(map(str, IDS)), "--gripper-id", str(GRIPPER), "--plant", "mujoco")
    with BusEmulator(*args) as emulator:
        yield emulator


@pytest.fixture(autouse=True)
def clear_faults(bus: BusEmulator) -> Iterator[None]:
    yield
    bus.inject("clear")


PATIENT_WATCHDOG = {"watchdog_periods": 500}
"""2 s at 4 ms: these tests pause between packets, which the kernel never does; the Bus
Watchdog's own tests are in test_dynamixel_watchdog.py."""


def settings(port: str, **overrides: Any) -> DynamixelSettings:
    return DynamixelSettings(port=port, **{"gripper_id": GRIPPER, **WIDE_TIMING,
                                           **PATIENT_WATCHDOG, **overrides})


def active_driver(port: str, **overrides: Any) -> contextlib.AbstractAsyncContextManager:
    return active(DynamixelDriver(settings(port, **overrides)), CONTROL)


def read_servo(port_path: str, dxl_id: int, address: int, size: int) -> int:
    """One register straight from the bus with the plain SDK, not through the driver."""
    port = PortHandler(port_path)
    port.openPort()
    try:
        sdk = PacketHandler(2.0)
        read = sdk.read1ByteTxRx if size == 1 else sdk.read4ByteTxRx
        value, result, _ = read(port, dxl_id, address)
        assert result == 0, sdk.getTxRxResult(result)
        return int(value)
    finally:
        port.closePort()


async def grip(driver: ManagedDriver, opening: float | None, seconds: float) -> None:
    """Stream the arm where it is with ``opening`` for the gripper."""
    q = (await driver.read()).q
    for _ in range(int(seconds / PERIOD_S)):
        applied = await driver.write(Command(kind=CommandKind.POSITION, q=q, gripper=opening))
        assert applied.accepted, applied
        await asyncio.sleep(PERIOD_S)


# ---------------------------------------------------------------------------- motion


async def test_gripper_closes_and_opens_the_plant_and_read_reports_metres(
    bus: BusEmulator,
) -> None:
    async with active_driver(bus.port) as driver:
        await grip(driver, 0.085, 0.3)
        wide = (await driver.read()).gripper
        await grip(driver, 0.0, 0.4)
        closed = (await driver.read()).gripper
        await grip(driver, 0.03, 0.4)
        partly = (await driver.read()).gripper
    assert wide == pytest.approx(0.085, abs=2 * TICK_M)
    assert closed is not None and abs(closed) < 2 * TICK_M
    assert partly == pytest.approx(0.03, abs=2 * TICK_M)
    # The bus itself agrees: goal and present position of servo 7 are the ticks of 3 cm.
    ticks_3cm = round(CLOSED_TICKS + 0.03 / 0.085 * (OPEN_TICKS - CLOSED_TICKS))
    assert read_servo(bus.port, GRIPPER, 116, 4) == ticks_3cm
    assert abs(read_servo(bus.port, GRIPPER, 132, 4) - ticks_3cm) <= 2


async def test_openings_beyond_the_travel_are_clipped(bus: BusEmulator) -> None:
    async with active_driver(bus.port) as driver:
        await grip(driver, 0.5, 0.2)
        wide = (await driver.read()).gripper
        await grip(driver, -0.1, 0.3)
        narrow = (await driver.read()).gripper
    assert wide == pytest.approx(0.085, abs=2 * TICK_M)
    assert narrow is not None and abs(narrow) < 2 * TICK_M
    assert read_servo(bus.port, GRIPPER, 116, 4) == CLOSED_TICKS


async def test_hold_stop_and_no_opening_leave_the_gripper_alone(bus: BusEmulator) -> None:
    async with active_driver(bus.port) as driver:
        q = (await driver.read()).q
        await driver.write(Command(kind=CommandKind.POSITION, q=q, gripper=0.0))
        # At once, while the fingers still move: a hold that made "where it is" the gripper's
        # goal would stop them half-way; one that obeyed the opening here would open them.
        held = await driver.write(Command(kind=CommandKind.HOLD, gripper=0.085))
        await asyncio.sleep(0.3)
        after_hold = (await driver.read()).gripper
        stopped = await driver.write(Command(kind=CommandKind.STOP, gripper=0.085))
        await grip(driver, None, 0.2)
        after_none = (await driver.read()).gripper
        assert driver.state is DriverState.ACTIVE
    assert held.accepted and stopped.accepted
    assert after_hold is not None and abs(after_hold) < 2 * TICK_M
    assert after_none is not None and abs(after_none) < 2 * TICK_M
    assert read_servo(bus.port, GRIPPER, 116, 4) == CLOSED_TICKS


async def test_nonfinite_opening_is_refused_and_moves_nothing(bus: BusEmulator) -> None:
    async with active_driver(bus.port) as driver:
        await grip(driver, 0.085, 0.3)
        q = (await driver.read()).q
        applied = await driver.write(Command(kind=CommandKind.POSITION, q=q, gripper=math.nan))
        await asyncio.sleep(0.1)
        assert (await driver.read()).gripper == pytest.approx(0.085, abs=2 * TICK_M)
    assert not applied.accepted and applied.reason is ReasonCode.NONFINITE


async def test_bring_up_configures_the_gripper_and_aclose_releases_it(bus: BusEmulator) -> None:
    port = PortHandler(bus.port)
    port.openPort()
    try:
        assert PacketHandler(2.0).write1ByteTxRx(port, GRIPPER, 11, 1)[0] == 0  # velocity mode
    finally:
        port.closePort()
    async with active_driver(bus.port) as driver:
        await driver.read()
        dynamixel = driver.driver
        assert isinstance(dynamixel, DynamixelDriver) and dynamixel.bus is not None
        assert GRIPPER in dynamixel.bus.models
    assert read_servo(bus.port, GRIPPER, 11, 1) == 5  # current-based position mode
    assert read_servo(bus.port, GRIPPER, 102, 2) == round(300 / 2.69)  # squeeze: 300 mA
    assert read_servo(bus.port, 1, 11, 1) == 3  # the joints: plain position mode
    assert read_servo(bus.port, GRIPPER, 64, 1) == 0  # torque off after aclose


async def test_a_squeeze_current_above_the_servos_current_limit_refuses_to_start(
        bus: BusEmulator) -> None:
    driver = DynamixelDriver(settings(bus.port, gripper_current_ma=4000.0))  # XM430: 3209 mA
    with pytest.raises(DeviceFault, match=r"servo id 7 .*refused writing 1487 to Goal Current"):
        await driver.connect()
        await driver.configure(CONTROL)
    await driver.aclose()


async def test_a_driver_without_gripper_id_ignores_the_gripper(bus: BusEmulator) -> None:
    async with active_driver(bus.port) as driver:
        await grip(driver, 0.085, 0.3)  # the plant's gripper open, then released
    async with active_driver(bus.port, gripper_id=None) as driver:
        await grip(driver, 0.0, 0.2)
        sample = await driver.read()
    assert sample.gripper is None
    assert read_servo(bus.port, GRIPPER, 64, 1) == 0  # never switched on
    assert abs(read_servo(bus.port, GRIPPER, 132, 4) - OPEN_TICKS) <= 2  # still open


# ---------------------------------------------------------------------------- faults


async def test_missing_gripper_servo_is_init_error_naming_it(bus: BusEmulator) -> None:
    driver = DynamixelDriver(settings(bus.port, gripper_id=9))
    with pytest.raises(DriverInitError) as caught:
        await driver.connect()
    await driver.aclose()
    message = str(caught.value)
    assert "gripper servo id 9 does not answer" in message
    assert "`gripper_id`" in message and bus.port in message


@pytest.mark.parametrize(("bit", "name"), [("overload", "overload"),
                                           ("overheating", "overheating")])
async def test_gripper_hardware_error_is_controller_fault_naming_the_id(
    bus: BusEmulator, bit: str, name: str
) -> None:
    async with active_driver(bus.port) as driver:
        await driver.read()
        bus.inject("hardware_error", id=GRIPPER, bit=bit)
        with pytest.raises(DeviceFault):
            await driver.read()
        assert driver.fault is ReasonCode.CONTROLLER_FAULT
        assert f"servo id {GRIPPER} (gripper): {name}" in driver.fault_detail


async def test_silent_gripper_is_link_lost_naming_the_id(bus: BusEmulator) -> None:
    async with active_driver(bus.port) as driver:
        await driver.read()
        bus.inject("silent", id=GRIPPER)
        with pytest.raises(DriverIOError):
            await driver.read()
        assert driver.fault is ReasonCode.LINK_LOST
        assert f"servo id {GRIPPER} (gripper) on {bus.port} stopped answering" in (
            driver.fault_detail)


async def test_gripper_hardware_error_before_connect_refuses_to_start(bus: BusEmulator) -> None:
    bus.inject("hardware_error", id=GRIPPER, bit="input_voltage")
    driver = ManagedDriver(DynamixelDriver(settings(bus.port)))
    try:
        with pytest.raises(DeviceFault, match=r"servo id 7 \(gripper\): input voltage"):
            await driver.configure(CONTROL)
    finally:
        await driver.aclose()


# ---------------------------------------------------------------------------- other ticks


async def test_tick_flags_and_settings_agree_on_a_reversed_gripper() -> None:
    # This gripper closes towards lower ticks; the kinematic plant follows goals at once.
    ticks = {"gripper_open_ticks": 3000, "gripper_closed_ticks": 1500}
    flags = ("--gripper-open-ticks", "3000", "--gripper-closed-ticks", "1500")
    with BusEmulator("--ids", "1,2,3", "--gripper-id", "5", *flags) as small:
        three = {"ids": (1, 2, 3), "offsets_rad": (0.0,) * 3, "directions": (1,) * 3}
        driver = ManagedDriver(DynamixelDriver(settings(small.port, gripper_id=5, **three,
                                                        **ticks)))
        control = ControlConfig(dof=3, period_ns=CONTROL.period_ns, q_lower=(-3.0,) * 3,
                                q_upper=(3.0,) * 3, v_max=(3.0,) * 3)
        try:
            await driver.configure(control)
            await driver.activate()
            q = (await driver.read()).q
            await driver.write(Command(kind=CommandKind.POSITION, q=q, gripper=0.017))
            await asyncio.sleep(0.05)
            opening = (await driver.read()).gripper
        finally:
            await driver.aclose()
        goal = read_servo(small.port, 5, 116, 4)
    assert opening == pytest.approx(0.017, abs=0.085 / 1500)
    assert goal == 1500 + round(0.017 / 0.085 * 1500)


# ---------------------------------------------------------------------------- bad settings


@pytest.mark.parametrize(("table", "key"), [
    ({"gripper_id": 3}, "gripper_id"),
    ({"gripper_id": 300}, "gripper_id"),
    ({"gripper_id": "7"}, "gripper_id"),
    ({"gripper_id": True}, "gripper_id"),
    ({"gripper_id": 7, "gripper_open_ticks": 5000}, "gripper_open_ticks"),
    ({"gripper_id": 7, "gripper_closed_ticks": -1}, "gripper_closed_ticks"),
    ({"gripper_id": 7, "gripper_closed_ticks": 2048}, "gripper_closed_ticks"),
    ({"gripper_id": 7, "gripper_open_ticks": 20.5}, "gripper_open_ticks"),
    ({"gripper": 7}, "gripper"),
    ({"gripper_id": 7, "gripper_current_ma": 0.0}, "gripper_current_ma"),
    ({"gripper_id": 7, "gripper_current_ma": 6000.0}, "gripper_current_ma"),
    ({"gripper_id": 7, "gripper_current_ma": float("nan")}, "gripper_current_ma"),
])
def test_bad_gripper_settings_are_refused_naming_the_key(table: dict[str, Any], key: str) -> None:
    with pytest.raises(SettingsError, match=rf"(\.{key}:|: {key}:)"):
        DynamixelDriver.from_mapping({"port": "/dev/ttyUSB0", **table})


def test_emulator_refuses_a_gripper_id_that_is_a_joint(capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    with pytest.raises(SystemExit):
        parse_args(["--ids", "1,2,3", "--gripper-id", "2"])
    assert "--gripper-id" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        parse_args(["--gripper-id", "7", "--gripper-open-ticks", "9", "--gripper-closed-ticks",
                    "9"])
