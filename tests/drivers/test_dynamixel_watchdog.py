"""The X-series Bus Watchdog (98): real dynamixel_sdk over a real pty to the bus emulator.

The driver clears it at activation, arms it with the first position setpoint, feeds it with
every packet and disables it on deactivate; when the packets stop, every servo stops on its own
and refuses goals until 0 is written to 98. The emulator's test control port peeks at the
control tables and the plant's ground truth; after the driver has let go of the port, the bare
SDK checks what a servo in Bus Watchdog Error answers. These tests use a 1 s watchdog: on the
shared 2-core test machine a test process was once silent for 0.47 s under load. The last tests
run the default (120 ms at 8 ms): they kill a driver process outright (SIGKILL) while it streams
toward a far target; this file run as a script is that child.

Stop bound (docs/operations.md, "Device-side watchdogs"): the watchdog time at the cell's 8 ms
period and 100 ms packet budget (10 periods = 80 ms, raised to one retried packet, 108 ms,
rounded up to 6 units: 120 ms), plus the plant's stopping time (STOPPING_S), plus a margin for
a loaded 2-core test machine (MARGIN_S). The emulator stops a servo by holding where it is:
the kinematic plant is at rest one 2 ms step later; the MuJoCo arm has no servo velocity limit
behind a far goal, reaches about 12 rad/s on joint 0 within the watchdog time, and its held
position rings for about half a second (measured: 0.54-0.65 s).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
import time
from collections.abc import Iterator
from typing import Any

import pytest
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from assurance.reasons import ReasonCode
from drivers.base import Command, CommandKind, ControlConfig, DeviceFault, DriverState
from drivers.dynamixel.driver import DynamixelDriver
from drivers.dynamixel.settings import DynamixelSettings, device_watchdog
from drivers.lifecycle import ManagedDriver
from stubs.dynamixel_bus.launch import WIDE_TIMING, BusEmulator
from stubs.fault_control import inject
from tests.drivers.support import (
    GroundTruth,
    active,
    seconds_to_standstill,
    start_script,
    wait_for_line,
    wait_until_moving,
)

IDS = (1, 2, 3, 4, 5, 6)
PERIOD_S = 0.008  # manifests/sim-dynamixel.toml
CONTROL = ControlConfig(dof=6, period_ns=int(PERIOD_S * 1e9), q_lower=(-3.0,) * 6,
                        q_upper=(3.0,) * 6, v_max=(3.0,) * 6)
BUS_WATCHDOG, GOAL_POSITION, PRESENT_POSITION = 98, 116, 132
WATCHDOG_UNITS = 6  # the default at 8 ms with the manifest's (and WIDE_TIMING's) 100 ms budget
WATCHDOG_S = WATCHDOG_UNITS * 0.020
TEST_PERIODS, TEST_UNITS = 125, 50  # 1 s
TEST_WATCHDOG_S = TEST_UNITS * 0.020
DATA_RANGE_ERROR = 4
STOPPING_S = {"kinematic": 0.002, "mujoco": 0.8}
MARGIN_S = 0.25
FAR_RAD = 2.5


@pytest.fixture(scope="module")
def bus() -> Iterator[BusEmulator]:
    with BusEmulator("--ids", ",".join(map(str, IDS))) as emulator:
        yield emulator


@pytest.fixture(autouse=True)
def power_cycle(bus: BusEmulator) -> Iterator[None]:
    yield
    bus.inject("clear")


def driver(port: str, **overrides: Any) -> DynamixelDriver:
    return DynamixelDriver(DynamixelSettings(port=port, **{**WIDE_TIMING, **overrides}))


def driver_1s(port: str, **overrides: Any) -> DynamixelDriver:
    return driver(port, **{"watchdog_periods": TEST_PERIODS, **overrides})


def watchdogs(bus: BusEmulator) -> list[int]:
    """Bus Watchdog (98) of every servo, as its control table holds it (signed)."""
    return [inject(bus.fault_address, "peek", id=i, item=BUS_WATCHDOG)["value"] for i in IDS]


def ground_truth(bus: BusEmulator) -> GroundTruth:
    return lambda: inject(bus.fault_address, "ground_truth")


async def stream(arm: ManagedDriver, q: tuple[float, ...], seconds: float) -> None:
    """Read and write every period, as the cell's loop does."""
    for _ in range(int(seconds / PERIOD_S)):
        await arm.read()
        assert (await arm.write(Command(kind=CommandKind.POSITION, q=q))).accepted
        await asyncio.sleep(PERIOD_S)


async def test_streaming_feeds_it_and_silence_stops_every_servo(bus: BusEmulator) -> None:
    async with active(driver_1s(bus.port), CONTROL) as arm:
        assert watchdogs(bus) == [0] * 6  # activation alone arms nothing
        here = (await arm.read()).q
        await stream(arm, here, 1.0)
        assert watchdogs(bus) == [TEST_UNITS] * 6 and arm.state is DriverState.ACTIVE

        await asyncio.sleep(2.5 * TEST_WATCHDOG_S)  # warden "hangs": no packet on the bus
        assert watchdogs(bus) == [-1] * 6
        assert max(abs(v) for v in ground_truth(bus)()["qd"]) == 0.0
        with pytest.raises(DeviceFault, match="Bus Watchdog expired"):
            await arm.read()  # the first packet after such a silence reads 98 back
        assert arm.state is DriverState.FAULT and arm.fault is ReasonCode.WATCHDOG
    with bare_sdk(bus.port) as (port, sdk):  # torque is off now; the error stays
        assert sdk.read1ByteTxRx(port, 3, BUS_WATCHDOG) == (0xFF, COMM_SUCCESS, 0)
        present = sdk.read4ByteTxRx(port, 3, PRESENT_POSITION)[0]
        assert sdk.write4ByteTxRx(port, 3, GOAL_POSITION, present + 100) == (
            COMM_SUCCESS, DATA_RANGE_ERROR)  # goal values are read-only
        assert sdk.write1ByteTxRx(port, 3, BUS_WATCHDOG, 0) == (COMM_SUCCESS, 0)  # clears it
        assert sdk.write4ByteTxRx(port, 3, GOAL_POSITION, present + 100) == (COMM_SUCCESS, 0)


async def test_deactivate_disables_it_and_activation_clears_an_error(bus: BusEmulator) -> None:
    async with active(driver_1s(bus.port), CONTROL) as arm:
        await stream(arm, (await arm.read()).q, 0.2)
        await arm.deactivate()
        await asyncio.sleep(2.5 * TEST_WATCHDOG_S)
        assert watchdogs(bus) == [0] * 6  # off, not expired
        await arm.activate()
        await stream(arm, (await arm.read()).q, 0.2)
        assert watchdogs(bus) == [TEST_UNITS] * 6
        await asyncio.sleep(2.5 * TEST_WATCHDOG_S)  # leave the servos in Bus Watchdog Error
    assert watchdogs(bus) == [-1] * 6
    async with active(driver_1s(bus.port), CONTROL) as arm:  # a new run on the same servos
        assert watchdogs(bus) == [0] * 6
        here = (await arm.read()).q
        target = (here[0] + 0.3, *here[1:])
        await stream(arm, target, 0.5)  # goals are taken again
        assert abs((await arm.read()).q[0] - target[0]) < 0.02


async def test_watchdog_periods_zero_leaves_it_off(bus: BusEmulator) -> None:
    async with active(driver_1s(bus.port, watchdog_periods=0), CONTROL) as arm:
        await stream(arm, (await arm.read()).q, 0.1)
        await asyncio.sleep(2.5 * TEST_WATCHDOG_S)
        assert watchdogs(bus) == [0] * 6
        await stream(arm, (await arm.read()).q, 0.05)
        assert arm.state is DriverState.ACTIVE, arm.fault_detail


@pytest.mark.parametrize(("periods", "period_s", "budget_ms", "units"), [
    (10, 0.008, 100.0, 6),   # manifests/sim-dynamixel.toml: one retried packet sets it
    (10, 0.008, 34.0, 4),    # the SDK's own budget: 10 periods, 80 ms
    (10, 0.004, 4.0, 2),     # FTDI latency timer at 1 ms, 250 Hz
    (0, 0.008, 100.0, 0),    # off
])
def test_watchdog_units(periods: int, period_s: float, budget_ms: float, units: int) -> None:
    settings = DynamixelSettings(port="/dev/null", watchdog_periods=periods,
                                 latency_budget_ms=budget_ms)
    assert settings.watchdog_units(period_s) == units


def test_a_watchdog_beyond_127_units_is_refused_with_the_key() -> None:
    with pytest.raises(ValueError, match="watchdog_periods: 400 periods"):
        DynamixelSettings(port="/dev/null", watchdog_periods=400).watchdog_units(0.008)
    with pytest.raises(ValueError, match="watchdog_periods: must be at least 0, got -1"):
        DynamixelSettings(port="/dev/null", watchdog_periods=-1)


@pytest.mark.parametrize("plant", ["kinematic", "mujoco"])  # mujoco: manifests/sim-dynamixel
def test_a_killed_driver_leaves_the_arm_at_rest_within_the_bound(plant: str) -> None:
    with BusEmulator("--ids", ",".join(map(str, IDS)), "--plant", plant) as bus:
        truth = ground_truth(bus)
        child = start_script(__file__, bus.port)
        try:
            wait_for_line(child, "STREAMING")
            start = wait_until_moving(truth, child, joint=0, min_rad_s=0.2, timeout_s=10.0)
            armed = watchdogs(bus)
            os.kill(child.pid, signal.SIGKILL)
            killed = time.monotonic()
        finally:
            child.kill()
            child.wait()
        seconds, rest = seconds_to_standstill(truth, since=killed, timeout_s=2.0)
        bound = WATCHDOG_S + STOPPING_S[plant] + MARGIN_S
        print(f"\n{plant}: at rest {seconds * 1e3:.0f} ms after SIGKILL (bound "
              f"{bound * 1e3:.0f} ms), joint 0 moved {rest['q'][0] - start['q'][0]:.3f} rad")
        assert armed == [WATCHDOG_UNITS] * 6  # the default at the manifest's period and budget
        assert seconds < bound
        assert rest["q"][0] < start["q"][0] + FAR_RAD - 1.0  # stopped, not arrived
        assert watchdogs(bus) == [-1] * 6


@contextlib.contextmanager
def bare_sdk(port_path: str) -> Iterator[tuple[PortHandler, PacketHandler]]:
    port = PortHandler(port_path)
    port.openPort()
    try:
        yield port, PacketHandler(2.0)
    finally:
        port.closePort()


async def stream_toward_far_target(port: str) -> None:
    """The child: the real driver sends the far target every period until it is killed."""
    arm = ManagedDriver(driver(port))
    await arm.configure(CONTROL)
    await arm.activate()
    here = (await arm.read()).q
    command = Command(kind=CommandKind.POSITION, q=(here[0] + FAR_RAD, *here[1:]))
    print("STREAMING", flush=True)
    for _ in range(int(30.0 / PERIOD_S)):  # the parent kills it long before
        await arm.read()
        applied = await arm.write(command)
        if not applied.accepted:
            sys.exit(f"setpoint refused: {applied.reason} {arm.fault_detail}")
        await asyncio.sleep(PERIOD_S)


if __name__ == "__main__":
    asyncio.run(stream_toward_far_target(sys.argv[1]))


@pytest.mark.parametrize(("table", "on"), [({}, True), ({"watchdog_periods": 1}, True),
                                           ({"watchdog_periods": 0}, False)])
def test_the_watchdog_a_trial_is_told_of_is_the_one_configured(table: dict[str, Any],
                                                              on: bool) -> None:
    """``device_watchdog`` is what `warden trial` reports as the device's stop, and None (no
    trial) when 0 switches the Bus Watchdog off (issue 15, item 14: reported on at 0)."""
    said = device_watchdog(DynamixelSettings(port="/dev/null", **table))
    assert (said is not None) == on
    if on:
        assert f"for {table.get('watchdog_periods', 10)} control periods" in str(said)
