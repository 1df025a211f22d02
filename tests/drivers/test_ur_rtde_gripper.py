"""The UR gripper through the driver: real ur_rtde (receive, control and IO interfaces), real
TCP, the emulated controller with its MuJoCo plant, whose gripper is wired to tool digital
output 0 and standard analog input 0 (0-10 V for 0-0.085 m).

The tests share one active driver (closing one costs about a second); each starts with the
gripper open. The emulator's test-only control port answers ``io_state``: the output bits, the
plant's true gripper opening and how many client packages set each kind of output. The IO
recipes, a driver without a gripper and link loss are in test_ur_rtde_gripper_io.py.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator, Iterator
from typing import Any

import pytest
import pytest_asyncio

from assurance.reasons import ReasonCode
from drivers.base import Command, CommandKind, ControlConfig, DriverState
from drivers.lifecycle import ManagedDriver
from drivers.ur_rtde.driver import URRTDEDriver
from drivers.ur_rtde.settings import URSettings
from stubs.fault_control import inject
from stubs.ur_controller.launch import EmulatedController
from tests.drivers.support import active

CONTROL = ControlConfig(dof=6, period_ns=2_000_000, q_lower=(-6.28,) * 6, q_upper=(6.28,) * 6,
                        v_max=(3.14,) * 6)
OPEN, CLOSED = 0.085, 0.0
TOOL_OUTPUT_0 = 1 << 16
TOOL = "tool_digital_output"


PATIENT_WATCHDOG = 2500
"""Control periods (5 s): these tests pause between writes, which the kernel never does; the
watchdog's own tests are in test_ur_watchdog.py."""
PATIENT_STALL = 200
"""RTDE periods (0.4 s, under the 0.5 s call timeout): one driver serves the whole module, and
an emulator starved for 0.1 s on a loaded 2-core test machine must not fault it for every
later test; stall detection has its own tests (test_ur_tables.py, test_ur_link_loss.py)."""


def gripper_settings(host: str, **extra: Any) -> URSettings:
    return URSettings(host=host, gripper_output=0, **{"watchdog_periods": PATIENT_WATCHDOG,
                                                      "stall_periods": PATIENT_STALL, **extra})


def io_state(host: str, control_port: int) -> dict[str, Any]:
    return inject((host, control_port), "io_state")


def state_of(emulator: EmulatedController) -> dict[str, Any]:
    return io_state(emulator.host, int(emulator.info["control_port"]))


async def grip(driver: ManagedDriver, opening: float | None, seconds: float) -> None:
    """Read, then stream the first position read with ``opening``, at 500 Hz, as the cell's
    loop does."""
    q = (await driver.read()).q
    for _ in range(int(seconds / 0.002)):
        applied = await driver.write(Command(kind=CommandKind.POSITION, q=q, gripper=opening))
        assert applied.accepted, applied.reason
        await driver.read()
        await asyncio.sleep(0.002)


@pytest.fixture(scope="module")
def emulator() -> Iterator[EmulatedController]:
    with EmulatedController(plant="mujoco") as controller:
        yield controller


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def shared_arm(emulator: EmulatedController) -> AsyncIterator[ManagedDriver]:
    emulator.clear()
    async with active(URRTDEDriver(gripper_settings(emulator.host), name="ur5e"), CONTROL) as arm:
        yield arm


@pytest_asyncio.fixture(loop_scope="module")
async def arm(shared_arm: ManagedDriver, emulator: EmulatedController
              ) -> AsyncIterator[ManagedDriver]:
    """The shared active driver, fault-free, with the gripper open at the start of every test."""
    assert shared_arm.state is DriverState.ACTIVE, shared_arm.fault_detail
    emulator.clear()
    await grip(shared_arm, OPEN, 0.3)
    yield shared_arm


on_shared_loop = pytest.mark.asyncio(loop_scope="module")


@on_shared_loop
async def test_closing_and_opening_move_the_plants_gripper_and_read_reports_metres(
    arm: ManagedDriver, emulator: EmulatedController,
) -> None:
    assert (await arm.read()).gripper == pytest.approx(OPEN, abs=1e-3)
    await grip(arm, CLOSED, 0.3)
    truth = state_of(emulator)
    assert truth["digital_output_bits"] & TOOL_OUTPUT_0
    assert truth["gripper_m"] < 0.005
    assert (await arm.read()).gripper == pytest.approx(truth["gripper_m"], abs=5e-4)
    await grip(arm, OPEN, 0.3)
    truth = state_of(emulator)
    assert not truth["digital_output_bits"] & TOOL_OUTPUT_0
    assert (await arm.read()).gripper == pytest.approx(truth["gripper_m"], abs=5e-4)
    assert truth["gripper_m"] == pytest.approx(OPEN, abs=1e-3)


@on_shared_loop
async def test_the_output_is_written_only_when_the_commanded_state_changes(
    arm: ManagedDriver, emulator: EmulatedController,
) -> None:
    before = state_of(emulator)["output_packages"][TOOL]
    await grip(arm, OPEN, 0.1)  # already open
    await grip(arm, None, 0.1)  # no gripper command at all
    assert state_of(emulator)["output_packages"][TOOL] == before
    await grip(arm, CLOSED, 0.2)  # 100 ticks, one change
    await grip(arm, 0.03, 0.1)  # still below half: still closed
    assert state_of(emulator)["output_packages"][TOOL] == before + 1
    await grip(arm, 0.05, 0.1)
    assert state_of(emulator)["output_packages"][TOOL] == before + 2


@on_shared_loop
async def test_hold_and_stop_leave_the_gripper_as_it_is(
    arm: ManagedDriver, emulator: EmulatedController,
) -> None:
    await grip(arm, CLOSED, 0.3)
    before = state_of(emulator)["output_packages"][TOOL]
    assert (await arm.write(Command(kind=CommandKind.HOLD, gripper=OPEN))).accepted
    assert (await arm.hold()).accepted
    assert (await arm.write(Command(kind=CommandKind.STOP, gripper=OPEN))).accepted
    await asyncio.sleep(0.2)
    truth = state_of(emulator)
    assert truth["output_packages"][TOOL] == before
    assert truth["gripper_m"] < 0.005
    assert (await arm.read()).gripper < 0.005


@on_shared_loop
async def test_a_non_finite_opening_is_refused_and_switches_nothing(
    arm: ManagedDriver, emulator: EmulatedController,
) -> None:
    before = state_of(emulator)["output_packages"][TOOL]
    q = (await arm.read()).q
    applied = await arm.write(Command(kind=CommandKind.POSITION, q=q, gripper=math.nan))
    assert not applied.accepted and applied.reason is ReasonCode.NONFINITE
    assert state_of(emulator)["output_packages"][TOOL] == before
    assert arm.state is DriverState.ACTIVE


@on_shared_loop
async def test_a_lost_output_write_is_sent_again_once_the_readback_disagrees(
    arm: ManagedDriver, emulator: EmulatedController,
) -> None:
    """ur_rtde's IO interface loses its first write after the controller dropped its session,
    without an error: the driver checks actual_digital_output_bits and writes once more."""
    before = state_of(emulator)["output_packages"][TOOL]
    inject((emulator.host, int(emulator.info["control_port"])), "lose_io_write", count=1)
    await grip(arm, CLOSED, 0.6)
    truth = state_of(emulator)
    assert truth["digital_output_bits"] & TOOL_OUTPUT_0
    assert truth["gripper_m"] < 0.005
    assert truth["output_packages"][TOOL] == before + 1  # the lost one is not counted
    await grip(arm, CLOSED, 0.3)  # confirmed now: nothing more is written
    assert state_of(emulator)["output_packages"][TOOL] == before + 1
