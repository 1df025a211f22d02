"""URRTDEDriver under faults and bad input: real ur_rtde against the emulated controller.

Every test builds its own driver (a fault leaves a driver in FAULT, as it should), and clears
the module's emulator before and after. Whatever is bad gets a clear error naming the host.
"""

from __future__ import annotations

import asyncio
import math
import socket
import threading
from collections.abc import Iterator

import numpy as np
import pytest

from assurance.reasons import ReasonCode
from drivers.base import (
    Command,
    CommandKind,
    ControlConfig,
    DeviceFault,
    DriverInitError,
    DriverState,
)
from drivers.lifecycle import ManagedDriver
from drivers.settings import SettingsError
from drivers.ur_rtde.driver import URRTDEDriver
from drivers.ur_rtde.settings import URSettings
from stubs.ur_controller.launch import EmulatedController, free_loopback_host

PERIOD_S = 0.002
CONTROL = ControlConfig(dof=6, period_ns=int(PERIOD_S * 1e9), q_lower=(-3.0,) * 6,
                        q_upper=(3.0,) * 6, v_max=(1.0,) * 6)


@pytest.fixture(scope="module")
def emulator() -> Iterator[EmulatedController]:
    with EmulatedController() as controller:
        yield controller


async def stream(driver: ManagedDriver, command: Command, seconds: float) -> None:
    for _ in range(int(seconds / PERIOD_S)):
        await driver.write(command)
        await asyncio.sleep(PERIOD_S)


async def test_protective_stop_faults_the_driver_with_the_controller_reason(
    emulator: EmulatedController,
) -> None:
    emulator.clear()
    arm = ManagedDriver(URRTDEDriver(URSettings(host=emulator.host), name="ur5e"))
    try:
        await arm.configure(CONTROL)
        await arm.activate()
        q = (await arm.read()).q
        emulator.inject("protective_stop")
        await asyncio.sleep(0.05)
        with pytest.raises(DeviceFault, match="PROTECTIVE_STOP"):
            await arm.read()
        assert arm.state is DriverState.FAULT
        assert arm.fault is ReasonCode.CONTROLLER_FAULT
        refused = await arm.write(Command(kind=CommandKind.POSITION, q=q))
        assert not refused.accepted and refused.reason is ReasonCode.CONTROLLER_FAULT
    finally:
        await arm.aclose()
        emulator.clear()


async def test_activate_restarts_the_control_script_after_a_cleared_stop(
    emulator: EmulatedController,
) -> None:
    emulator.clear()
    first = ManagedDriver(URRTDEDriver(URSettings(host=emulator.host)))
    await first.configure(CONTROL)
    emulator.inject("protective_stop")
    emulator.clear()  # the stop is released, but the control script has ended, as on a real arm
    await asyncio.sleep(0.05)  # a few RTDE packages, so both sessions have seen it
    try:
        await first.activate()
        q = np.array((await first.read()).q)
        await stream(first, Command(kind=CommandKind.POSITION, q=tuple(q + 0.05)), 0.3)
        assert np.abs(np.array((await first.read()).q) - (q + 0.05)).max() < 0.01
    finally:
        await first.aclose()


async def test_connect_during_an_emergency_stop_says_so(emulator: EmulatedController) -> None:
    emulator.clear()
    emulator.inject("estop")
    driver = ManagedDriver(URRTDEDriver(URSettings(host=emulator.host)))
    try:
        with pytest.raises(DeviceFault, match="EMERGENCY_STOP"):
            await driver.configure(CONTROL)
        assert driver.fault is ReasonCode.E_STOP
    finally:
        await driver.aclose()
        emulator.clear()


async def test_wrong_joint_count_is_an_init_error_naming_the_host(
    emulator: EmulatedController,
) -> None:
    emulator.clear()
    driver = URRTDEDriver(URSettings(host=emulator.host))
    seven = ControlConfig(dof=7, period_ns=2_000_000, q_lower=(-1.0,) * 7, q_upper=(1.0,) * 7,
                          v_max=(1.0,) * 7)
    try:
        await driver.connect()
        with pytest.raises(DriverInitError, match=emulator.host):
            await driver.configure(seven)
    finally:
        await driver.aclose()


async def test_unreachable_host_is_an_init_error_naming_host_and_port() -> None:
    host = free_loopback_host()  # nothing listens there
    settings = URSettings(host=host, reconnect_attempts=1, reconnect_backoff_s=0.01)
    driver = URRTDEDriver(settings)
    try:
        with pytest.raises(DriverInitError, match=rf"{host}:29999.*check `host`"):
            await driver.connect()
    finally:
        await driver.aclose()


async def test_a_server_that_is_not_a_ur_controller_is_refused() -> None:
    host = free_loopback_host()
    stop = threading.Event()
    with socket.create_server((host, 29999)) as impostor:
        greeter = threading.Thread(target=_greet_and_hang_up, args=(impostor, stop))
        greeter.start()
        driver = URRTDEDriver(URSettings(host=host, reconnect_attempts=0,
                                         connect_timeout_s=0.5))
        try:
            with pytest.raises(DriverInitError, match="not a UR dashboard server"):
                await driver.connect()
        finally:
            stop.set()
            greeter.join()
            await driver.aclose()


def _greet_and_hang_up(server: socket.socket, stop: threading.Event) -> None:
    """An SSH-like server on the dashboard port: answers, but not as a UR controller."""
    server.settimeout(0.05)
    while not stop.is_set():
        try:
            connection, _ = server.accept()
        except TimeoutError:
            continue
        with connection:
            connection.sendall(b"SSH-2.0-OpenSSH_9.6\r\n")


async def test_unsupported_controller_version_is_an_init_error_naming_the_host() -> None:
    with EmulatedController(version="3.15.7") as cb3:
        driver = URRTDEDriver(URSettings(host=cb3.host))
        try:
            with pytest.raises(DriverInitError, match=rf"{cb3.host}.*URControl 3\.15\.7"):
                await driver.connect()
        finally:
            await driver.aclose()


def test_bad_settings_name_the_key_and_the_host() -> None:
    table = {"host": "10.0.0.7", "servo_gain": 50.0}
    refusal = r"arm\.driver\.servo_gain: must be at least 100, got 50\.0"
    with pytest.raises(SettingsError, match=refusal):
        URSettings.from_mapping(table, "arm.driver")
    with pytest.raises(SettingsError, match=refusal):
        URRTDEDriver.from_mapping(table, "arm.driver")  # the one from_mapping of drivers/base.py
    with pytest.raises(SettingsError, match="unknown key"):
        URSettings.from_mapping({"host": "10.0.0.7", "lookahead": 0.1}, "arm.driver")


@pytest.mark.parametrize(("key", "value"), [
    ("servo_lookahead_s", 0.02), ("servo_lookahead_s", 0.25), ("servo_gain", 2500.0),
    ("servo_velocity", 3.5), ("servo_acceleration", -1.0), ("frequency_hz", 1000.0),
    ("servo_gain", math.nan), ("host", " "), ("watchdog_periods", 1),
    ("watchdog_periods", 10_001), ("watchdog_periods", -1),
])
def test_settings_outside_the_library_ranges_are_refused(key: str, value: object) -> None:
    with pytest.raises(SettingsError, match=key.split("_")[0]):
        URSettings.from_mapping({"host": "10.0.0.7", key: value}, "arm.driver")


def test_settings_accept_the_range_edges() -> None:
    settings = URSettings(host="10.0.0.7", servo_lookahead_s=0.03, servo_gain=2000.0,
                          servo_velocity=3.14, servo_acceleration=40.0)
    assert settings.stall_after_s == pytest.approx(0.1)
    assert settings.watchdog_frequency_hz(0.002) == pytest.approx(20.0)  # 25 periods, 50 ms
    assert URSettings(host="10.0.0.7", watchdog_periods=0).watchdog_frequency_hz(0.002) is None
    assert URSettings(host="10.0.0.7", watchdog_periods=2).watchdog_frequency_hz(0.002) == 250.0


async def test_connect_retries_while_the_controller_comes_up() -> None:
    host = free_loopback_host()
    settings = URSettings(host=host, reconnect_attempts=10, reconnect_backoff_s=0.3)
    driver = URRTDEDriver(settings)
    connecting = asyncio.ensure_future(driver.connect())
    await asyncio.sleep(0.3)  # the first attempts find nothing there
    assert not connecting.done()
    try:
        with EmulatedController(host=host):
            await asyncio.wait_for(connecting, timeout=15.0)
            await driver.configure(CONTROL)
            assert len((await driver.read()).q) == 6
            await driver.aclose()
    finally:
        connecting.cancel()
        await driver.aclose()
