"""The UR gripper's IO path: the emulated controller answering ur_rtde's IO interface, a driver
without a gripper, and a gripper that outlives a lost link. Real ur_rtde, real TCP, an emulator
with the kinematic plant (its gripper moves at once) and the gripper wiring every emulated
controller has: tool digital output 0 closes it, standard analog input 0 reports 0-10 V.

The link-loss scenario runs in a child process (this file run as a script): ur_rtde's IO
interface kills its process from a destructor when it is dropped the wrong way, and that must
fail a test, not take pytest down.
"""

from __future__ import annotations

import asyncio
import json
import socket
import struct
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
import rtde_io
import rtde_receive

from assurance.reasons import ReasonCode
from drivers.base import Command, CommandKind, DriverError, DriverState
from drivers.lifecycle import ManagedDriver
from drivers.ur_rtde.driver import URRTDEDriver
from drivers.ur_rtde.settings import URSettings
from stubs.fault_control import inject
from stubs.ur_controller.launch import EmulatedController
from tests.drivers.support import run_script
from tests.drivers.test_ur_rtde_gripper import (
    CLOSED,
    CONTROL,
    OPEN,
    TOOL,
    TOOL_OUTPUT_0,
    grip,
    gripper_settings,
    io_state,
    state_of,
)

CHILD_TIMEOUT_S = 60.0

# The 16 input recipes ur_rtde 1.6.5's RTDEIOInterface sets up, in its order (lower range).
IO_RECIPES = [
    ["input_int_register_23"],
    ["input_int_register_23", "standard_digital_output_mask", "standard_digital_output"],
    ["input_int_register_23", "tool_digital_output_mask", "tool_digital_output"],
    ["input_int_register_23", "speed_slider_mask", "speed_slider_fraction"],
    ["input_int_register_23", "standard_analog_output_mask", "standard_analog_output_type",
     "standard_analog_output_0", "standard_analog_output_1"],
    ["input_int_register_23", "configurable_digital_output_mask", "configurable_digital_output"],
    *[["input_int_register_23", f"input_int_register_{n}"] for n in range(18, 23)],
    *[["input_int_register_23", f"input_double_register_{n}"] for n in range(18, 23)],
]
UR_TYPES = {"input_int_register": "INT32", "input_double_register": "DOUBLE",
            "speed_slider_mask": "UINT32", "speed_slider_fraction": "DOUBLE",
            "standard_analog_output_0": "DOUBLE", "standard_analog_output_1": "DOUBLE"}
"""RTDE guide types of those fields; every other one (masks and output bytes) is UINT8."""


@pytest.fixture(scope="module")
def emulator() -> Iterator[EmulatedController]:
    with EmulatedController() as controller:
        yield controller


@pytest.fixture(autouse=True)
def _cleared(emulator: EmulatedController) -> None:
    emulator.clear()


def test_every_io_recipe_is_answered_with_the_ur_types(emulator: EmulatedController) -> None:
    with socket.create_connection((emulator.host, 30004), timeout=2.0) as sock:
        _request(sock, "V", struct.pack(">H", 2))
        for number, names in enumerate(IO_RECIPES, start=1):
            answer = _request(sock, "I", ",".join(names).encode() + b",")
            assert answer[0] == number, f"recipe {names} refused: {answer[1:]!r}"
            assert answer[1:].decode().split(",") == [_ur_type(name) for name in names]


def test_tool_output_drives_the_gripper_and_the_analog_input_reports_it(
    emulator: EmulatedController,
) -> None:
    receive = rtde_receive.RTDEReceiveInterface(
        emulator.host, 500.0, ["timestamp", "actual_digital_output_bits", "standard_analog_input0"])
    io = rtde_io.RTDEIOInterface(emulator.host)
    try:
        assert io.setToolDigitalOut(0, True) and io.setStandardDigitalOut(3, True)
        closed = _settle(lambda: receive.getStandardAnalogInput0(), lambda v: v < 0.05)
        # Each package lands within a few ms, but a second small write right after the first
        # can wait out a TCP delayed ACK (~40 ms): wait for the bits, do not assume them.
        _settle(receive.getActualDigitalOutputBits, lambda bits: bits == TOOL_OUTPUT_0 | 1 << 3)
        assert receive.getDigitalOutState(16) and receive.getDigitalOutState(3)
        assert not receive.getDigitalOutState(17)
        assert state_of(emulator)["gripper_m"] == pytest.approx(closed / 10.0 * OPEN, abs=1e-3)
        assert io.setToolDigitalOut(0, False)
        opened = _settle(lambda: receive.getStandardAnalogInput0(), lambda v: v > 9.9)
        assert opened == pytest.approx(10.0, abs=0.1)
        assert receive.getActualDigitalOutputBits() == 1 << 3  # other outputs keep their level
    finally:
        io.setStandardDigitalOut(3, False)
        io.disconnect()  # a clean disconnect: the destructor then has nothing left to do
        receive.disconnect()


async def test_without_a_gripper_nothing_is_switched_or_reported(
    emulator: EmulatedController,
) -> None:
    before = state_of(emulator)["output_packages"].get(TOOL, 0)
    driver = ManagedDriver(URRTDEDriver(URSettings(host=emulator.host), name="ur5e"))
    try:
        await driver.configure(CONTROL)
        await driver.activate()
        sample = await driver.read()
        assert sample.gripper is None
        applied = await driver.write(Command(kind=CommandKind.POSITION, q=sample.q, gripper=0.0))
        assert applied.accepted
        assert state_of(emulator)["output_packages"].get(TOOL, 0) == before
    finally:
        await driver.aclose()


def test_gripper_survives_link_loss_and_the_client_process_too(
    emulator: EmulatedController,
) -> None:
    try:
        child = run_script(__file__, emulator.host, emulator.info["control_port"],
                           timeout_s=CHILD_TIMEOUT_S)
    finally:
        emulator.clear()
    assert child.returncode == 0, f"client exited {child.returncode}:\n{child.stderr[-2000:]}"
    result = json.loads(child.stdout.split("RESULT ", 1)[1])
    assert result["fault"] == ReasonCode.LINK_LOST, result["detail"]
    assert result["closed_before"] < 0.005
    assert result["reopened_after"] == pytest.approx(OPEN, abs=1e-3)
    assert result["state"] == DriverState.CLOSED


# -- helpers --------------------------------------------------------------------------------------


def _settle(read: Callable[[], float], done: Callable[[float], bool], timeout_s: float = 2.0
            ) -> float:
    deadline = time.monotonic() + timeout_s
    value = read()
    while not done(value) and time.monotonic() < deadline:
        time.sleep(0.01)
        value = read()
    assert done(value), f"stuck at {value}"
    return value


def _ur_type(name: str) -> str:
    prefix = name.rsplit("_", 1)[0]
    return UR_TYPES.get(name) or UR_TYPES.get(prefix) or "UINT8"


def _request(sock: socket.socket, kind: str, payload: bytes) -> bytes:
    sock.sendall(struct.pack(">HB", 3 + len(payload), ord(kind)) + payload)
    while True:
        size, got = struct.unpack(">HB", _exactly(sock, 3))
        body = _exactly(sock, size - 3)
        if got == ord(kind):
            return body


def _exactly(sock: socket.socket, count: int) -> bytes:
    data = b""
    while len(data) < count:
        chunk = sock.recv(count - len(data))
        if not chunk:
            raise ConnectionError("the emulator closed the connection")
        data += chunk
    return data


# -- the child process of the link-loss test --------------------------------------------------


async def link_loss_scenario(host: str, control_port: int) -> dict[str, Any]:
    """Close the gripper, lose the link, come back, reopen it through the same driver."""
    driver = ManagedDriver(URRTDEDriver(gripper_settings(host), name="ur5e"))
    await driver.configure(CONTROL)
    await driver.activate()
    await grip(driver, CLOSED, 0.3)
    closed_before = io_state(host, control_port)["gripper_m"]
    inject((host, control_port), "disconnect")  # every session dropped, new ones refused
    try:
        for _ in range(2500):
            await grip(driver, OPEN, 0.002)
    except (AssertionError, DriverError):
        pass  # the lifecycle has turned to FAULT: that is the point
    outcome = {"fault": driver.fault, "detail": driver.fault_detail,
               "closed_before": closed_before}
    # Back after the control interface has given up its own reconnect (see test_ur_link_loss).
    await asyncio.sleep(0.5)
    inject((host, control_port), "clear")
    await driver.driver.connect()
    await driver.driver.activate()
    q = (await driver.driver.read()).q
    for _ in range(150):
        await driver.driver.write(Command(kind=CommandKind.POSITION, q=q, gripper=OPEN))
        await asyncio.sleep(0.002)
    outcome["reopened_after"] = (await driver.driver.read()).gripper
    await driver.aclose()
    return {**outcome, "state": driver.state}


if __name__ == "__main__":
    host_arg, port_arg = sys.argv[1:3]
    print("RESULT " + json.dumps(asyncio.run(link_loss_scenario(host_arg, int(port_arg)))),
          flush=True)
