"""HOLD keeps the arm where it was last commanded, whatever the device reports meanwhile.

Each vendor driver against its emulator, over its real transport: the arm is commanded to where
it is, then the emulator reports joint 0 half a radian off (a reading glitch: the plant does
not move by it) while the driver is told HOLD every period, as the loop does in an operator's
takeover. Before the fix every driver held at the device's present reading, so each hold
servoed the arm toward the glitched value: the true joint left its setpoint by tenths of a
radian within the glitch. Now a hold writes the last setpoint again, and the true joint stays
within the servo's tracking of it (asserted from the emulator's ground truth, never timed).

Where a driver has no setpoint to hold, it must read the device once: the first STOP of a
Dynamixel arm (the goal where the servo is), the first hold after a stop on UR and CiA 402 (the
stop's ramp left the arm where no setpoint said). A glitch exactly at that read made the
glitched value the target; now the driver judges each reading as the core does
(``drivers.plausible``) and takes an implausible one's place from the last plausible reading.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Sequence

from drivers.base import Command, CommandKind, ControlConfig, Driver
from drivers.canopen402.driver import CiA402Driver
from drivers.dynamixel.driver import DynamixelDriver
from drivers.dynamixel.settings import DynamixelSettings
from drivers.ur_rtde.driver import URRTDEDriver
from drivers.ur_rtde.settings import URSettings
from stubs.cia402_drive import DriveEmulator
from stubs.dynamixel_bus.launch import WIDE_TIMING, BusEmulator
from stubs.fault_control import inject
from stubs.ur_controller.launch import EmulatedController
from tests.drivers import cia402_testbed as cia402
from tests.drivers.support import active

OFFSET_RAD = 0.5
GLITCH_MS = 300
HOLDING_S = 0.25
"""Held this long inside the glitch: at the emulators' servo speeds a hold that chased the
reading moved the joint well past TOLERANCE_RAD (0.1-0.5 rad)."""
TOLERANCE_RAD = 0.01
HOLD = Command(kind=CommandKind.HOLD)

Truth = Callable[[], Sequence[float]]
"""The plant's true joints, from the emulator's side."""


def _limits(period_s: float) -> ControlConfig:
    return ControlConfig(dof=6, period_ns=int(period_s * 1e9), q_lower=(-3.0,) * 6,
                         q_upper=(3.0,) * 6, v_max=(3.0,) * 6, a_max=(20.0,) * 6)


async def _held_through_a_glitch(driver: Driver, control: ControlConfig, truth: Truth,
                                 glitch: Callable[[], object], command: Command = HOLD
                                 ) -> float:
    """Command the arm where it is, glitch joint 0's reading, then ``command`` every period
    (a STOP once before the glitch too: the stop the glitch finds is a repeated one); the
    farthest the true joint 0 went from the setpoint meanwhile."""
    period_s = control.period_ns * 1e-9
    async with active(driver, control) as arm:
        here = Command(kind=CommandKind.POSITION, q=(await arm.read()).q)
        for _ in range(10):
            await arm.read()
            assert (await arm.write(here)).accepted
            await asyncio.sleep(period_s)
        if command.kind is CommandKind.STOP:
            assert (await arm.write(command)).accepted
        glitch()
        farthest, reported = 0.0, 0.0
        end = time.monotonic() + HOLDING_S
        while time.monotonic() < end:
            reported = max(reported, abs((await arm.read()).q[0] - here.q[0]))
            assert (await arm.write(command)).accepted
            farthest = max(farthest, abs(truth()[0] - here.q[0]))
            await asyncio.sleep(period_s)
        assert reported > OFFSET_RAD / 2  # the driver did read the glitch
    return farthest


async def test_the_ur_arm_holds_its_last_setpoint_through_a_reading_glitch() -> None:
    with EmulatedController() as emulator:
        address = (emulator.host, int(emulator.info["control_port"]))
        driver = URRTDEDriver(URSettings(host=emulator.host, watchdog_periods=250))
        moved = await _held_through_a_glitch(
            driver, _limits(0.002), lambda: inject(address, "ground_truth")["q"],
            lambda: inject(address, "reading_glitch", joint=0, offset=OFFSET_RAD,
                           duration_ms=GLITCH_MS))
    assert moved < TOLERANCE_RAD, f"the arm moved {moved:.3f} rad while held"


async def test_the_dynamixel_arm_holds_its_last_goal_through_a_reading_glitch() -> None:
    with BusEmulator("--ids", "1,2,3,4,5,6") as bus:
        driver = DynamixelDriver(DynamixelSettings(port=bus.port, **WIDE_TIMING))
        moved = await _held_through_a_glitch(
            driver, _limits(0.008), lambda: inject(bus.fault_address, "ground_truth")["q"],
            lambda: bus.inject("reading_glitch", joint=0, offset=OFFSET_RAD,
                               duration_ms=GLITCH_MS))
    assert moved < TOLERANCE_RAD, f"the arm moved {moved:.3f} rad while held"


async def test_a_stopped_dynamixel_arm_stays_stopped_through_a_reading_glitch() -> None:
    """In position mode STOP sets the goal where the servo is: once. Repeated, as every tick
    of E_STOP sends it, it re-read the position each time and chased the glitch."""
    with BusEmulator("--ids", "1,2,3,4,5,6") as bus:
        driver = DynamixelDriver(DynamixelSettings(port=bus.port, **WIDE_TIMING))
        moved = await _held_through_a_glitch(
            driver, _limits(0.008), lambda: inject(bus.fault_address, "ground_truth")["q"],
            lambda: bus.inject("reading_glitch", joint=0, offset=OFFSET_RAD,
                               duration_ms=GLITCH_MS), Command(kind=CommandKind.STOP))
    assert moved < TOLERANCE_RAD, f"the arm moved {moved:.3f} rad while stopped"


async def test_the_cia402_arm_holds_its_last_targets_through_a_reading_glitch() -> None:
    emulator = DriveEmulator(cia402.emulator_config("virtual", cia402.unique_virtual_channel()))
    with emulator:
        driver = CiA402Driver(cia402.driver_settings("virtual", emulator.config.channel))

        def truth() -> Sequence[float]:
            with emulator.lock:
                return emulator.plant.state().q

        moved = await _held_through_a_glitch(
            driver, cia402.control(), truth,
            lambda: emulator.inject("reading_glitch", joint=0, offset=OFFSET_RAD,
                                    duration_ms=GLITCH_MS))
    assert moved < TOLERANCE_RAD, f"the arm moved {moved:.3f} rad while held"


async def _glitched_at_the_first_read(driver: Driver, control: ControlConfig, truth: Truth,
                                      glitch: Callable[[], object], command: Command,
                                      stopped: bool = False) -> float:
    """Command the arm where it is (and, if ``stopped``, STOP it and let it rest, reading
    every period as the loop does); glitch joint 0's reading; then ``command`` with no read
    before it, so that its own read of the device is the first to see the glitch; then read
    and ``command`` every period. The farthest the true joint 0 went from where it rested."""
    period_s = control.period_ns * 1e-9
    async with active(driver, control) as arm:
        here = Command(kind=CommandKind.POSITION, q=(await arm.read()).q)
        for _ in range(10):
            await arm.read()
            assert (await arm.write(here)).accepted
            await asyncio.sleep(period_s)
        for _ in range(round(0.3 / period_s) if stopped else 0):
            await arm.read()
            assert (await arm.write(Command(kind=CommandKind.STOP))).accepted
            await asyncio.sleep(period_s)
        rest = truth()[0]
        glitch()
        await asyncio.sleep(3 * period_s)  # reported by the device now, and read by nobody
        assert (await arm.write(command)).accepted
        farthest, reported = 0.0, 0.0
        end = time.monotonic() + HOLDING_S
        while time.monotonic() < end:
            reported = max(reported, abs((await arm.read()).q[0] - rest))
            assert (await arm.write(command)).accepted
            farthest = max(farthest, abs(truth()[0] - rest))
            await asyncio.sleep(period_s)
        assert reported > OFFSET_RAD / 2  # the glitch lasted: the reads after saw it too
    return farthest


async def test_the_first_dynamixel_stop_takes_no_glitched_reading_for_its_goal() -> None:
    with BusEmulator("--ids", "1,2,3,4,5,6") as bus:
        driver = DynamixelDriver(DynamixelSettings(port=bus.port, **WIDE_TIMING))
        moved = await _glitched_at_the_first_read(
            driver, _limits(0.008), lambda: inject(bus.fault_address, "ground_truth")["q"],
            lambda: bus.inject("reading_glitch", joint=0, offset=OFFSET_RAD,
                               duration_ms=GLITCH_MS), Command(kind=CommandKind.STOP))
    assert moved < TOLERANCE_RAD, f"the arm moved {moved:.3f} rad after its first stop"


async def test_the_first_ur_hold_after_a_stop_takes_no_glitched_reading() -> None:
    with EmulatedController() as emulator:
        address = (emulator.host, int(emulator.info["control_port"]))
        driver = URRTDEDriver(URSettings(host=emulator.host, watchdog_periods=250))
        moved = await _glitched_at_the_first_read(
            driver, _limits(0.002), lambda: inject(address, "ground_truth")["q"],
            lambda: inject(address, "reading_glitch", joint=0, offset=OFFSET_RAD,
                           duration_ms=GLITCH_MS), HOLD, stopped=True)
    assert moved < TOLERANCE_RAD, f"the arm moved {moved:.3f} rad held after a stop"


async def test_the_first_cia402_hold_after_a_quick_stop_takes_no_glitched_reading() -> None:
    emulator = DriveEmulator(cia402.emulator_config("virtual", cia402.unique_virtual_channel()))
    with emulator:
        driver = CiA402Driver(cia402.driver_settings("virtual", emulator.config.channel))

        def truth() -> Sequence[float]:
            with emulator.lock:
                return emulator.plant.state().q

        control = cia402.control()
        control = ControlConfig(control.dof, control.period_ns, control.q_lower,
                                control.q_upper, control.v_max, a_max=(20.0,) * 6)
        moved = await _glitched_at_the_first_read(
            driver, control, truth,
            lambda: emulator.inject("reading_glitch", joint=0, offset=OFFSET_RAD,
                                    duration_ms=GLITCH_MS), HOLD, stopped=True)
    assert moved < TOLERANCE_RAD, f"the arm moved {moved:.3f} rad held after a quick stop"
