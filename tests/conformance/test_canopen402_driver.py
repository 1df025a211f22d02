"""The conformance suite against the CiA 402 driver, back to back over two transports.

``virtual``: the drive emulator runs in this process on python-can's in-process bus.
``udp_multicast``: it runs as a separate process (``python -m stubs.cia402_drive``) on a
multicast group and port unique to this module, one process for all of its tests: one robot,
many driver sessions. Each test first releases injected conditions (``clear``) and connects with
``reset_faults_on_connect``, as a recovery would after the previous test's EMCY. Both use the
real canopen and python-can.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator

import pytest

from assurance.reasons import ReasonCode
from drivers.canopen402.driver import CiA402Driver
from drivers.testing import DriverConformance, Harness
from stubs.cia402_drive import DriveEmulator
from stubs.cia402_drive.launch import unique_udp_bus
from stubs.fault_control import inject
from stubs.process import EmulatorProcess
from tests.drivers import cia402_testbed as arm

FAULTED_NODE = 3
EXPECTED = {
    "emcy": ReasonCode.CONTROLLER_FAULT,
    "heartbeat_stop": ReasonCode.LINK_LOST,
    "quick_stop": ReasonCode.CONTROLLER_FAULT,
}


def _harness(settings: object, inject_fault: object) -> Harness:
    return Harness(
        make_driver=lambda: CiA402Driver(settings),  # type: ignore[arg-type]
        control=arm.control(),
        inject=inject_fault,  # type: ignore[arg-type]
        expected_reason=EXPECTED,
        advance=asyncio.sleep,
    )


class TestCiA402OnVirtualBus(DriverConformance):
    FAULTS = tuple(EXPECTED)

    @pytest.fixture
    def harness(self) -> Iterator[Harness]:
        channel = arm.unique_virtual_channel()
        emulator = DriveEmulator(arm.emulator_config("virtual", channel)).start()
        try:
            yield _harness(arm.driver_settings("virtual", channel),
                           lambda name: emulator.inject(name, node=FAULTED_NODE))
        finally:
            emulator.stop()


@pytest.fixture(scope="module")
def udp_drives() -> Iterator[tuple[str, int, tuple[str, int]]]:
    group, port = unique_udp_bus()
    with EmulatorProcess("stubs.cia402_drive", *arm.emulator_args(group, port)) as process:
        yield group, port, ("127.0.0.1", int(process.info["fault_port"]))


class TestCiA402OnUdpMulticast(DriverConformance):
    FAULTS = tuple(EXPECTED)

    @pytest.fixture
    def harness(self, udp_drives: tuple[str, int, tuple[str, int]]) -> Harness:
        group, port, address = udp_drives
        inject(address, "clear")
        settings = arm.driver_settings("udp_multicast", group, udp_port=port,
                                       reset_faults_on_connect=True)
        return _harness(settings, lambda name: inject(address, name, node=FAULTED_NODE))
