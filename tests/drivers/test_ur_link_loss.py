"""Link loss and data stalls, with the driver in a child process.

ur_rtde's control interface reconnects on its own receive thread when its socket fails, and a
stalled link once took a client process down with it (exit 139). So each scenario runs the
driver in a fresh child (this file run as a script): a crash fails the test instead of taking
pytest with it. The child reports the lifecycle's verdict as one ``RESULT {json}`` line, after
checking that the same driver reconnects once the controller is back.
"""

from __future__ import annotations

import asyncio
import json
import sys
import time
from collections.abc import Iterator

import pytest

from assurance.reasons import ReasonCode
from drivers.base import Command, CommandKind, ControlConfig, Driver, DriverError, DriverState
from drivers.lifecycle import ManagedDriver
from drivers.ur_rtde.driver import URRTDEDriver
from drivers.ur_rtde.settings import URSettings
from stubs.fault_control import inject
from stubs.ur_controller.launch import EmulatedController
from tests.drivers.support import run_script

CONTROL = ControlConfig(dof=6, period_ns=2_000_000, q_lower=(-6.28,) * 6, q_upper=(6.28,) * 6,
                        v_max=(3.14,) * 6)
CHILD_TIMEOUT_S = 60.0
CONTROLLER_BACK_AFTER_S = 0.5


@pytest.fixture(scope="module")
def emulator() -> Iterator[EmulatedController]:
    with EmulatedController() as controller:
        yield controller


@pytest.mark.parametrize(("fault", "silent_s", "reason", "detail"), [
    # Our watchdog sees the timestamp stop long before the library's 2.5 s read deadline.
    ("data_stall", 0.0, ReasonCode.WATCHDOG, ("no new RTDE data",)),
    # Nobody reads for 3.5 s: the library's deadline closes the socket and its receive thread
    # tries to reconnect on its own (the path that crashed); the next read finds no link.
    ("data_stall", 3.5, ReasonCode.LINK_LOST, ("session closed",)),
    # Usually a read finds the session closed. If a servoJ races the EOF, ur_rtde itself tries
    # to reconnect inside that call and fails, on the refused port or on the dashboard answer
    # it parses the PolyScope version from while the controller drops it: still LINK_LOST.
    ("disconnect", 0.0, ReasonCode.LINK_LOST,
     ("session closed", "Could not connect", "PolyScopeVersion::parse failed")),
])
def test_the_client_process_survives_and_reports_the_reason(
    emulator: EmulatedController, fault: str, silent_s: float, reason: ReasonCode,
    detail: tuple[str, ...],
) -> None:
    emulator.clear()
    try:
        child = run_script(__file__, emulator.host, emulator.info["control_port"], fault,
                           silent_s, timeout_s=CHILD_TIMEOUT_S)
    finally:
        emulator.clear()
    assert child.returncode == 0, f"client exited {child.returncode}:\n{child.stderr[-2000:]}"
    result = json.loads(child.stdout.split("RESULT ", 1)[1])
    assert result["state"] == DriverState.CLOSED
    assert result["fault"] == reason
    assert any(text in result["detail"] for text in detail), result["detail"]
    assert result["reconnected"]
    assert result["close_s"] < 8.0


async def run_scenario(host: str, control_port: int, fault: str, silent_s: float) -> dict:
    """Stream, inject ``fault``, stay silent, then read and write until the lifecycle faults."""
    driver = ManagedDriver(URRTDEDriver(URSettings(host=host), name="ur5e"))
    await driver.configure(CONTROL)
    await driver.activate()
    hold_here = Command(kind=CommandKind.POSITION, q=(await driver.read()).q)
    for _ in range(25):
        await driver.write(hold_here)
        await asyncio.sleep(0.002)
    inject((host, control_port), fault)
    await asyncio.sleep(silent_s)
    deadline = time.monotonic() + 5.0
    while driver.state is DriverState.ACTIVE and time.monotonic() < deadline:
        try:
            await driver.read()
            await driver.write(hold_here)
        except DriverError:
            break
        await asyncio.sleep(0.002)
    outcome = {"fault": driver.fault, "detail": driver.fault_detail,
               "reconnected": await reconnect(driver.driver, host, control_port)}
    started = time.monotonic()
    await driver.aclose()
    return {**outcome, "state": driver.state, "close_s": time.monotonic() - started}


async def reconnect(driver: Driver, host: str, control_port: int) -> bool:
    """The controller comes back: connect() again reconnects the same interfaces (bounded).

    It comes back after CONTROLLER_BACK_AFTER_S, once ur_rtde's control interface has given
    up its own automatic reconnect. Back within milliseconds, while that reconnect is still
    running, and the library itself crashed the process in up to 70 % of runs here, whatever
    the driver did: that window is the library's, see the driver report.
    """
    await asyncio.sleep(CONTROLLER_BACK_AFTER_S)
    inject((host, control_port), "clear")
    await driver.connect()
    await driver.activate()
    return len((await driver.read()).q) == 6


if __name__ == "__main__":
    host_arg, port_arg, fault_arg, silent_arg = sys.argv[1:5]
    outcome = asyncio.run(run_scenario(host_arg, int(port_arg), fault_arg, float(silent_arg)))
    print("RESULT " + json.dumps(outcome), flush=True)
