"""The conformance suite against the Dynamixel driver: real dynamixel_sdk, real pty, our bus.

One emulator process serves the whole module; every test ends with ``clear`` (faults off,
torque off) so tests stay independent. Time is real: ``advance`` sleeps while the emulator
steps its plant on its own clock.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from typing import Any

import pytest

from assurance.reasons import ReasonCode
from drivers.base import ControlConfig
from drivers.dynamixel.driver import DynamixelDriver
from drivers.dynamixel.settings import DynamixelSettings
from drivers.testing import DriverConformance, Harness
from stubs.dynamixel_bus.launch import WIDE_TIMING, BusEmulator

PERIOD_NS = 4_000_000  # 250 Hz: leaves the emulator's share of two cores to the emulator

FAULT_REQUESTS: dict[str, dict[str, Any]] = {
    "hardware_error": {"fault": "hardware_error", "id": 2, "bit": "overload"},
    "silent": {"fault": "silent", "id": 4},
    "crc_storm": {"fault": "crc", "count": 100_000},
}
"""Conformance fault name → emulator request. A CRC storm outlasts every retry."""


@pytest.fixture(scope="module")
def bus() -> Iterator[BusEmulator]:
    with BusEmulator("--ids", "1,2,3,4,5,6") as emulator:
        yield emulator


@pytest.fixture
def harness(bus: BusEmulator) -> Iterator[Harness]:
    settings = DynamixelSettings(port=bus.port, **WIDE_TIMING)

    def inject(name: str) -> None:
        request = dict(FAULT_REQUESTS[name])
        bus.inject(request.pop("fault"), **request)

    async def advance(seconds: float) -> None:
        await asyncio.sleep(seconds)

    control = ControlConfig(
        dof=6, period_ns=PERIOD_NS, q_lower=(-3.0,) * 6, q_upper=(3.0,) * 6, v_max=(3.0,) * 6
    )
    yield Harness(
        make_driver=lambda: DynamixelDriver(settings),
        control=control,
        inject=inject,
        expected_reason={
            "hardware_error": ReasonCode.CONTROLLER_FAULT,
            "silent": ReasonCode.LINK_LOST,
            "crc_storm": ReasonCode.LINK_LOST,
        },
        advance=advance,
    )
    bus.inject("clear")


class TestDynamixelDriverConformance(DriverConformance):
    FAULTS = tuple(FAULT_REQUESTS)
