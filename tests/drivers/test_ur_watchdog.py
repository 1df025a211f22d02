"""The controller-side RTDE watchdog: real ur_rtde against the emulated controller.

The driver arms it with the first motion setpoint, every setpoint feeds it, deactivate removes
it; when the setpoints stop, the controller stops the control script and the arm. These tests
use a 1 s watchdog: on the shared 2-core test machine this process was once silent for 0.47 s
under load, which would stop an arm on a 50 ms watchdog, rightly, but not because of the driver.
The last tests run the default (50 ms): they kill a driver process outright (SIGKILL) while it
streams toward a far target, and time how long the emulator's ground truth takes to show the
arm at rest; this file run as a script is that child.

Stop bound (docs/operations.md, "Device-side watchdogs"): the watchdog time (25 periods, 50 ms),
plus one controller cycle before the controller sees it (2 ms), plus the plant's stopping time
(STOPPING_S: the emulator holds the measured position, the kinematic plant is at rest one 2 ms
step later, the MuJoCo arm's position loop took about 55 ms from 0.5 rad/s: 80 ms), plus a
margin for a loaded 2-core test machine (ground-truth polls, scheduling: MARGIN_S).
"""

from __future__ import annotations

import asyncio
import math
import os
import signal
import sys
import time
from collections.abc import Iterator
from typing import Any

import pytest

from assurance.reasons import ReasonCode
from drivers.base import Command, CommandKind, ControlConfig, DeviceFault, DriverState
from drivers.lifecycle import ManagedDriver
from drivers.ur_rtde.driver import URRTDEDriver
from drivers.ur_rtde.settings import URSettings
from stubs.fault_control import inject
from stubs.ur_controller.launch import EmulatedController
from tests.drivers.support import (
    GroundTruth,
    active,
    seconds_to_standstill,
    start_script,
    wait_for_line,
    wait_until_moving,
)

PERIOD_S = 0.002
CONTROL = ControlConfig(dof=6, period_ns=int(PERIOD_S * 1e9), q_lower=(-6.28,) * 6,
                        q_upper=(6.28,) * 6, v_max=(3.14,) * 6)
WATCHDOG_S = 25 * PERIOD_S  # the default, watchdog_periods = 25
TEST_PERIODS = 500
TEST_WATCHDOG_S = TEST_PERIODS * PERIOD_S
ARMED = {"input_int_register_0": 1 / TEST_WATCHDOG_S}
"""What ur_rtde's setWatchdog arms on the controller: the command register, 1 Hz here."""
RUNNING, PLAYING, STOPPED = 7, 2, 1
NORMAL_SAFETY_BITS = 1 << 0
PROGRAM_RUNNING_BIT = 1 << 1
CONTROLLER_CYCLE_S = 0.002
STOPPING_S = {"kinematic": 0.002, "mujoco": 0.08}
MARGIN_S = 0.25
FAR_RAD = 3.0
CHILD_READY_TIMEOUT_S = 60.0


@pytest.fixture(scope="module")
def emulator() -> Iterator[EmulatedController]:
    with EmulatedController() as controller:
        yield controller


def _status(emulator: EmulatedController) -> dict[str, Any]:
    """The controller's status words and armed watchdogs (test control port)."""
    return inject(_control_address(emulator), "status")


def _ground_truth(emulator: EmulatedController) -> GroundTruth:
    address = _control_address(emulator)
    return lambda: inject(address, "ground_truth")


def _control_address(emulator: EmulatedController) -> tuple[str, int]:
    return emulator.host, int(emulator.info["control_port"])


def arm_at(emulator: EmulatedController, **settings: Any) -> URRTDEDriver:
    return URRTDEDriver(URSettings(host=emulator.host, **{"watchdog_periods": TEST_PERIODS,
                                                          **settings}))


async def stream(driver: ManagedDriver, command: Command, seconds: float) -> None:
    """Read and write every period, as the cell's loop does."""
    for _ in range(int(seconds / PERIOD_S)):
        await driver.read()
        await driver.write(command)
        await asyncio.sleep(PERIOD_S)


async def hold_command(driver: ManagedDriver) -> Command:
    return Command(kind=CommandKind.POSITION, q=(await driver.read()).q)


async def test_streaming_feeds_the_watchdog_and_silence_stops_the_script(
    emulator: EmulatedController,
) -> None:
    emulator.clear()
    fired = _status(emulator)["watchdogs"]["fired"]  # since the emulator started
    async with active(arm_at(emulator), CONTROL) as arm:
        assert _status(emulator)["watchdogs"]["armed"] == {}  # activation alone arms nothing
        await stream(arm, await hold_command(arm), 1.0)
        armed = _status(emulator)
        assert armed["watchdogs"] == {"armed": ARMED, "fired": fired}
        assert armed["runtime_state"] == PLAYING and arm.state is DriverState.ACTIVE

        await asyncio.sleep(2.5 * TEST_WATCHDOG_S)  # warden "hangs": nothing reaches it
        stopped = _status(emulator)
        assert stopped["watchdogs"] == {"armed": {}, "fired": fired + 1}  # and removed
        # What a real controller reports after a program stop: no safety stop, arm powered.
        assert stopped["runtime_state"] == STOPPED
        assert stopped["robot_mode"] == RUNNING
        assert stopped["safety_bits"] == NORMAL_SAFETY_BITS
        assert not stopped["robot_status_bits"] & PROGRAM_RUNNING_BIT
        with pytest.raises(DeviceFault, match="RTDE watchdog armed"):
            await arm.read()  # the same words, through ur_rtde's receive interface
        assert arm.state is DriverState.FAULT and arm.fault is ReasonCode.WATCHDOG


async def test_refused_setpoints_kick_it_and_a_stop_restores_it(
    emulator: EmulatedController,
) -> None:
    emulator.clear()
    fired = _status(emulator)["watchdogs"]["fired"]
    async with active(arm_at(emulator), CONTROL) as arm:
        held = await hold_command(arm)
        await stream(arm, held, 0.1)
        bad = Command(kind=CommandKind.POSITION, q=(math.nan, *held.q[1:]))
        for _ in range(int(0.3 / PERIOD_S)):  # nothing goes out but kicks
            assert (await arm.write(bad)).reason is ReasonCode.NONFINITE
            await asyncio.sleep(PERIOD_S)
        await stream(arm, Command(kind=CommandKind.VELOCITY, qd=(0.3, 0, 0, 0, 0, 0)), 0.1)
        assert (await arm.write(Command(kind=CommandKind.STOP))).accepted
        await stream(arm, await hold_command(arm), 0.3)
        assert _status(emulator)["watchdogs"] == {"armed": ARMED, "fired": fired}
        assert arm.state is DriverState.ACTIVE, arm.fault_detail


async def test_deactivate_removes_it_and_activate_arms_it_again(
    emulator: EmulatedController,
) -> None:
    emulator.clear()
    fired = _status(emulator)["watchdogs"]["fired"]
    async with active(arm_at(emulator), CONTROL) as arm:
        await stream(arm, await hold_command(arm), 0.1)
        await arm.deactivate()
        await asyncio.sleep(2.5 * TEST_WATCHDOG_S)
        idle = _status(emulator)
        assert idle["watchdogs"] == {"armed": {}, "fired": fired}  # removed, not fired
        assert idle["runtime_state"] == STOPPED and idle["safety_bits"] == NORMAL_SAFETY_BITS
        await arm.activate()  # uploads the control script again
        await stream(arm, await hold_command(arm), 0.1)
        assert _status(emulator)["watchdogs"]["armed"] == ARMED
        assert arm.state is DriverState.ACTIVE, arm.fault_detail


async def test_watchdog_periods_zero_arms_nothing(emulator: EmulatedController) -> None:
    emulator.clear()
    fired = _status(emulator)["watchdogs"]["fired"]
    async with active(arm_at(emulator, watchdog_periods=0), CONTROL) as arm:
        await stream(arm, await hold_command(arm), 0.1)
        await asyncio.sleep(2.5 * TEST_WATCHDOG_S)
        assert _status(emulator)["watchdogs"] == {"armed": {}, "fired": fired}
        await stream(arm, await hold_command(arm), 0.05)
        assert arm.state is DriverState.ACTIVE, arm.fault_detail


@pytest.mark.parametrize(("plant", "mode"), [
    ("kinematic", "position"),   # servoJ to the far target itself, every period
    ("kinematic", "velocity"),   # speedJ toward it: without a watchdog it never ends
    ("mujoco", "velocity"),      # the plant of manifests/sim-ur5e-rtde.toml
])
def test_a_killed_driver_leaves_the_arm_at_rest_within_the_bound(plant: str, mode: str) -> None:
    with EmulatedController(plant=plant) as emulator:
        truth = _ground_truth(emulator)
        child = start_script(__file__, emulator.host, mode)
        try:
            wait_for_line(child, "STREAMING")
            start = wait_until_moving(truth, child, joint=0, min_rad_s=0.2, timeout_s=10.0)
            armed = _status(emulator)["watchdogs"]["armed"]
            os.kill(child.pid, signal.SIGKILL)
            killed = time.monotonic()
        finally:
            child.kill()
            child.wait()
        seconds, rest = seconds_to_standstill(truth, since=killed, timeout_s=2.0)
        bound = WATCHDOG_S + CONTROLLER_CYCLE_S + STOPPING_S[plant] + MARGIN_S
        print(f"\n{plant}/{mode}: at rest {seconds * 1e3:.0f} ms after SIGKILL "
              f"(bound {bound * 1e3:.0f} ms), joint 0 moved "
              f"{rest['q'][0] - start['q'][0]:.3f} rad")
        assert armed == {"input_int_register_0": 1 / WATCHDOG_S}  # the default: 20 Hz
        assert seconds < bound
        assert rest["q"][0] < FAR_RAD - 1.0  # stopped by the watchdog, not by arriving
        stopped = _status(emulator)
        assert stopped["watchdogs"]["fired"] == 1
        assert (stopped["runtime_state"], stopped["robot_mode"], stopped["safety_bits"]) == (
            STOPPED, RUNNING, NORMAL_SAFETY_BITS)


async def stream_toward_far_target(host: str, mode: str) -> None:
    """The child: the real driver streams toward FAR_RAD on joint 0 until it is killed."""
    driver = ManagedDriver(URRTDEDriver(URSettings(host=host), name="ur5e"))
    await driver.configure(CONTROL)
    await driver.activate()
    start = (await driver.read()).q
    if mode == "position":
        command = Command(kind=CommandKind.POSITION, q=(start[0] + FAR_RAD, *start[1:]))
    else:
        command = Command(kind=CommandKind.VELOCITY, qd=(0.5, 0, 0, 0, 0, 0))
    print("STREAMING", flush=True)
    for _ in range(int(30.0 / PERIOD_S)):  # the parent kills it long before
        await driver.read()
        applied = await driver.write(command)
        if not applied.accepted:
            sys.exit(f"setpoint refused: {applied.reason} {driver.fault_detail}")
        await asyncio.sleep(PERIOD_S)


if __name__ == "__main__":
    asyncio.run(stream_toward_far_target(sys.argv[1], sys.argv[2]))
