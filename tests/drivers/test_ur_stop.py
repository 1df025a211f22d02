"""STOP on the UR arm, as the loop sends it: every tick of E_STOP and CONTROLLER_STOP.

stopJ is a blocking round trip to the control script (it first waits for fresh RTDE data, then
for the script to finish the command). Sent every 2 ms period it collapsed the cell's loop to
about 200 Hz on the robot PC (issue 15, item 3). An arm already brought to rest by the driver's
own stop needs no second one: the repeated STOP is answered from a snapshot and only kicks the
RTDE watchdog. Counted against the emulated controller, never timed.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterator
from typing import Any

import pytest

from assurance.reasons import ReasonCode
from drivers.base import Command, CommandKind, ControlConfig, DriverError, DriverState
from drivers.lifecycle import ManagedDriver
from drivers.ur_rtde.driver import URRTDEDriver
from drivers.ur_rtde.settings import URSettings
from stubs.fault_control import inject
from stubs.ur_controller.launch import EmulatedController
from tests.drivers.support import active

PERIOD_S = 0.002
CONTROL = ControlConfig(dof=6, period_ns=int(PERIOD_S * 1e9), q_lower=(-6.28,) * 6,
                        q_upper=(6.28,) * 6, v_max=(3.14,) * 6)
WATCHDOG_PERIODS = 250
"""0.5 s: long enough for a loaded test machine, short enough to fire within the test."""
PLAYING = 2
STOP = Command(kind=CommandKind.STOP)


@pytest.fixture(scope="module")
def emulator() -> Iterator[EmulatedController]:
    with EmulatedController() as controller:
        yield controller


def _query(emulator: EmulatedController, what: str) -> dict[str, Any]:
    return inject((emulator.host, int(emulator.info["control_port"])), what)


async def _stop_for(arm: ManagedDriver, seconds: float) -> int:
    """Read and write STOP every period, as the loop does in E_STOP; the ticks it took."""
    ticks = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        sample = await arm.read()
        applied = await arm.write(STOP)
        assert applied.accepted and applied.kind is CommandKind.STOP, applied
        assert applied.q == pytest.approx(sample.q, abs=1e-3)  # where the arm stopped
        ticks += 1
        await asyncio.sleep(PERIOD_S)
    return ticks


async def _stream(arm: ManagedDriver, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        q = (await arm.read()).q
        await arm.write(Command(kind=CommandKind.POSITION, q=q))
        await asyncio.sleep(PERIOD_S)


async def test_a_repeated_stop_reaches_the_script_once_and_keeps_the_watchdog_fed(
    emulator: EmulatedController,
) -> None:
    emulator.clear()
    driver = URRTDEDriver(URSettings(host=emulator.host, watchdog_periods=WATCHDOG_PERIODS))
    async with active(driver, CONTROL) as arm:
        await _stream(arm, 0.1)  # arms the watchdog
        fired = _query(emulator, "status")["watchdogs"]["fired"]
        before = _query(emulator, "motion")["stop_commands"]
        # Three watchdog times of STOP: the watchdog must be fed without stopJ every tick.
        ticks = await _stop_for(arm, 3 * WATCHDOG_PERIODS * PERIOD_S)
        after = _query(emulator, "motion")["stop_commands"]
        assert ticks > 10
        assert after - before <= 2, f"{after - before} stops reached the script in {ticks} ticks"
        status = _query(emulator, "status")
        assert status["runtime_state"] == PLAYING and status["watchdogs"]["fired"] == fired
        assert arm.state is DriverState.ACTIVE, arm.fault_detail

        # Motion since the last stop: the next STOP goes to the script again.
        await _stream(arm, 0.05)
        await _stop_for(arm, 0.05)
        assert _query(emulator, "motion")["stop_commands"] > after
        assert arm.state is DriverState.ACTIVE, arm.fault_detail


async def test_the_stop_runs_while_the_ticks_go_on_and_its_failure_faults_the_driver() -> None:
    """The stop's round trips are not the tick's: a stop that cannot finish (no RTDE data, so
    it waits out the stall bound and fails) is answered at once, the reads in between repeat
    the last sample, and the failure reaches the lifecycle at a later call (WATCHDOG)."""
    with EmulatedController() as emulator:
        driver = URRTDEDriver(URSettings(host=emulator.host, watchdog_periods=WATCHDOG_PERIODS))
        async with active(driver, CONTROL) as arm:
            await _stream(arm, 0.1)
            last = await arm.read()
            _query(emulator, "data_stall")
            applied = await arm.write(STOP)  # waited for the stall bound and raised, before
            assert applied.accepted and applied.q == last.q
            calls = 0
            # Which bound ends it depends on where the stall catches ur_rtde: the data's stall
            # bound, or the stop's own deadline when stopJ itself is waiting.
            with pytest.raises(DriverError, match=r"no new RTDE data|stop took longer than"):
                while calls < 10_000:  # bounded: the stop fails within its stall bound
                    assert (await arm.read()).seq == last.seq  # no new sample meanwhile
                    calls += 1
                    await asyncio.sleep(PERIOD_S)
            assert calls > 0
            assert arm.state is DriverState.FAULT and arm.fault is ReasonCode.WATCHDOG


async def test_the_watchdog_is_armed_before_the_first_tick_not_by_it(
    emulator: EmulatedController,
) -> None:
    """setWatchdog is a blocking round trip (20-100 ms against the emulator): sent with the
    first setpoint it stalled the loop's first tick past a 50 ms state watchdog, a WATCHDOG
    fault that cost a real-device run its cycle. The loop arms it before its timer starts
    (``before_first_tick``); the first setpoint then finds it armed."""
    emulator.clear()
    driver = URRTDEDriver(URSettings(host=emulator.host, watchdog_periods=WATCHDOG_PERIODS))
    async with active(driver, CONTROL) as arm:
        assert _query(emulator, "status")["watchdogs"]["armed"] == {}
        await arm.before_first_tick()
        assert arm.state is DriverState.ACTIVE
        armed = _query(emulator, "status")["watchdogs"]["armed"]
        assert armed != {}  # the controller has it before any setpoint
        q = (await arm.read()).q
        assert (await arm.write(Command(kind=CommandKind.POSITION, q=q))).accepted
        assert _query(emulator, "status")["watchdogs"]["armed"] == armed  # nothing re-armed


async def test_impedance_is_refused_not_turned_into_a_stop(emulator: EmulatedController) -> None:
    """The UR driver declares no IMPEDANCE (servoJ and speedJ only). The lifecycle refuses it
    with CONTROLLER_MODE_MISMATCH, and the driver called around the lifecycle refuses it too:
    it used to fall through to stopJ and report a STOP applied."""
    emulator.clear()
    driver = URRTDEDriver(URSettings(host=emulator.host))
    assert CommandKind.IMPEDANCE not in driver.capabilities
    async with active(driver, CONTROL) as arm:
        q = (await arm.read()).q
        impedance = Command(kind=CommandKind.IMPEDANCE, q=q, stiffness=(100.0,) * 6,
                            damping=(10.0,) * 6)
        refused = await arm.write(impedance)
        assert not refused.accepted and refused.reason is ReasonCode.CONTROLLER_MODE_MISMATCH
        applied = await driver.write(impedance)
        assert (applied.kind, applied.accepted, applied.reason) == (
            CommandKind.IMPEDANCE, False, ReasonCode.CONTROLLER_MODE_MISMATCH)
        assert arm.state is DriverState.ACTIVE
