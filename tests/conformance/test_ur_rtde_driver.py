"""The conformance suite against the UR RTDE driver: real ur_rtde, real TCP, emulated controller.

One emulator process serves the whole module (faults are cleared before every test); each test
builds its own driver, as the kernel would after a fault.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator

import pytest

from assurance.reasons import ReasonCode
from drivers.base import ControlConfig
from drivers.ur_rtde.driver import URRTDEDriver
from drivers.ur_rtde.settings import URSettings
from stubs.ur_controller.launch import EmulatedController
from tests.conformance.suite import DriverConformance, Harness

PERIOD_NS = 2_000_000  # 500 Hz, the controller's own rate


@pytest.fixture(scope="module")
def emulator() -> Iterator[EmulatedController]:
    with EmulatedController() as controller:
        yield controller


@pytest.fixture
def harness(emulator: EmulatedController) -> Harness:
    emulator.clear()  # whatever the previous test injected

    async def advance(seconds: float) -> None:
        await asyncio.sleep(seconds)

    return Harness(
        # A call deadline for a loaded 2-core test machine, not a robot PC: under the full
        # suite a plain read once took over the default 0.5 s. Faults here never hang a call.
        make_driver=lambda: URRTDEDriver(URSettings(host=emulator.host, call_timeout_s=2.0),
                                         name="ur5e"),
        control=ControlConfig(dof=6, period_ns=PERIOD_NS, q_lower=(-6.28,) * 6,
                              q_upper=(6.28,) * 6, v_max=(3.14,) * 6),
        inject=emulator.inject,
        expected_reason={
            "protective_stop": ReasonCode.CONTROLLER_FAULT,
            "estop": ReasonCode.E_STOP,
            "data_stall": ReasonCode.WATCHDOG,
            "disconnect": ReasonCode.LINK_LOST,
        },
        advance=advance,
    )


class TestURRTDEDriverConformance(DriverConformance):
    FAULTS = ("protective_stop", "estop", "data_stall", "disconnect")
