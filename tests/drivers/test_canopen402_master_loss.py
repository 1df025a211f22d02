"""What an emulated CiA 402 drive does when its master goes away, seen from a bare canopen master.

No warden driver here: a plain canopen ``Network`` on the emulator's ``virtual`` bus writes the
drive's objects over SDO, sends NMT commands and produces (or stops) a master heartbeat, so
these tests check the emulator against CiA 301 / CiA 402 and not against our driver. A drive
watches the heartbeat its 0x1016 names from the first one it hears; a silence longer than the
consumer time is a heartbeat event: EMCY 0x8130, NMT PRE-OPERATIONAL (CiA 301's default error
behaviour) and the reaction 0x6007 asks for. NMT STOPPED and the reset commands lead to the same
reaction. The plant is the kinematic one: a joint that was moving stops, without any SYNC.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass

import canopen
import pytest
from canopen.sdo import SdoAbortedError

from stubs.cia402_drive import DriveEmulator
from stubs.cia402_drive.dictionary import object_dictionary
from stubs.cia402_drive.profile import PowerState
from stubs.cia402_drive.supervision import ConnectionLoss
from tests.drivers import cia402_testbed as arm

MASTER = 0x7F
NODE = 2
CONSUMER_MS = 50
HEARTBEAT_S = 0.01
SILENCE_S = 3 * CONSUMER_MS / 1000
NO_FOLLOWING_LIMIT = 0xFFFF_FFFF
CSP = 8
QUICK_STOP_HOLD = 6
SDO_VALUE_RANGE = 0x0609_0030
SHUTDOWN, SWITCH_ON, ENABLE_OPERATION = 0x06, 0x07, 0x0F
NO_ACTION, FAULT_SIGNAL, DISABLE_VOLTAGE, QUICK_STOP = 0, 1, 2, 3
OPERATIONAL = 5


@dataclass
class Bench:
    emulator: DriveEmulator
    network: canopen.Network
    node: canopen.RemoteNode

    def drive_state(self) -> PowerState:
        return self.emulator.drive(NODE).state

    def joint_qd(self) -> float:
        with self.emulator.lock:
            return self.emulator.plant.state().qd[arm.NODE_IDS.index(NODE)]

    def joint_q(self) -> float:
        with self.emulator.lock:
            return self.emulator.plant.state().q[arm.NODE_IDS.index(NODE)]


@pytest.fixture
def bench() -> Iterator[Bench]:
    channel = arm.unique_virtual_channel()
    emulator = DriveEmulator(arm.emulator_config("virtual", channel)).start()
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05  # disconnect waits one cycle for the reader thread
    network.connect(interface="virtual", channel=channel)
    try:
        node = network.add_node(canopen.RemoteNode(NODE, object_dictionary(NODE)))
        yield Bench(emulator, network, node)
    finally:
        network.disconnect()
        emulator.stop()


def enable_in_csp(bench: Bench, abort_option: int, consumer_ms: int = CONSUMER_MS) -> None:
    """The drive set up over SDO alone, OPERATIONAL and OPERATION ENABLED in CSP."""
    sdo = bench.node.sdo
    sdo[0x6007].raw = abort_option
    sdo[0x605A].raw = QUICK_STOP_HOLD
    sdo[0x6065].raw = NO_FOLLOWING_LIMIT  # the test's far target is not a following error
    sdo[0x1016][1].raw = MASTER << 16 | consumer_ms
    bench.node.nmt.state = "OPERATIONAL"
    sdo[0x6060].raw = CSP
    sdo[0x607A].raw = sdo[0x6064].raw  # start from where it is
    for command in (SHUTDOWN, SWITCH_ON, ENABLE_OPERATION):
        sdo[0x6040].raw = command
    assert bench.drive_state() is PowerState.OPERATION_ENABLED


def emcy_when(bench: Bench, code: int, timeout_s: float = 1.0) -> canopen.emcy.EmcyError:
    """The first EMCY with ``code`` the master has logged, waiting for it if need be."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        found = [entry for entry in bench.node.emcy.log if entry.code == code]
        if found:
            return found[0]
        time.sleep(0.005)
    raise AssertionError(f"no EMCY 0x{code:04X} within {timeout_s} s: "
                         f"{[hex(e.code) for e in bench.node.emcy.log]}")


def beating(bench: Bench) -> canopen.network.PeriodicMessageTask:
    """The master's heartbeat, OPERATIONAL, every 10 ms until stopped."""
    return bench.network.send_periodic(0x700 + MASTER, bytes([OPERATIONAL]), HEARTBEAT_S)


def test_monitoring_starts_with_the_first_heartbeat(bench: Bench) -> None:
    enable_in_csp(bench, QUICK_STOP)
    time.sleep(SILENCE_S)  # configured, never heard: nothing to miss yet
    assert bench.drive_state() is PowerState.OPERATION_ENABLED
    heartbeat = beating(bench)
    time.sleep(SILENCE_S)  # heard and still coming
    assert bench.drive_state() is PowerState.OPERATION_ENABLED
    heartbeat.stop()
    time.sleep(SILENCE_S)
    assert bench.drive_state() is PowerState.QUICK_STOP_ACTIVE
    assert bench.emulator.drive(NODE).connection_losses == [ConnectionLoss.HEARTBEAT]


def test_a_missed_heartbeat_is_an_emcy_pre_operational_and_a_quick_stop(bench: Bench) -> None:
    enable_in_csp(bench, QUICK_STOP)
    heartbeat = beating(bench)
    time.sleep(0.05)
    start = bench.joint_q()
    bench.node.sdo[0x607A].raw = bench.node.sdo[0x6064].raw + 2 * arm.COUNTS_PER_REV // 6
    time.sleep(0.05)  # no SYNC at all: the drives' own clock moves the plant
    assert abs(bench.joint_qd()) > 1.0
    heartbeat.stop()
    assert emcy_when(bench, 0x8130).register & 0x11 == 0x11  # communication + generic
    assert bench.drive_state() is PowerState.QUICK_STOP_ACTIVE
    assert bench.emulator.drive(NODE).node.nmt.state == "PRE-OPERATIONAL"
    statusword = bench.node.sdo[0x6041].raw
    assert statusword & 0x6F == 0x07  # QUICK STOP ACTIVE, as a master decodes it
    time.sleep(0.05)
    assert bench.joint_qd() == 0.0  # held where the quick stop found it
    assert abs(bench.joint_q() - start) < 1.0  # short of the target (2.09 rad away)
    heartbeat = beating(bench)  # the master is back: the event is resolved
    emcy_when(bench, 0x0000)
    heartbeat.stop()
    assert bench.node.sdo[0x1001].raw == 0
    assert bench.drive_state() is PowerState.QUICK_STOP_ACTIVE  # until the master decides


@pytest.mark.parametrize(("option", "state"), [
    (NO_ACTION, PowerState.OPERATION_ENABLED),
    (FAULT_SIGNAL, PowerState.FAULT),
    (DISABLE_VOLTAGE, PowerState.SWITCH_ON_DISABLED),
    (QUICK_STOP, PowerState.QUICK_STOP_ACTIVE),
])
def test_0x6007_chooses_the_reaction(bench: Bench, option: int, state: PowerState) -> None:
    enable_in_csp(bench, option)
    heartbeat = beating(bench)
    time.sleep(0.05)
    heartbeat.stop()
    time.sleep(SILENCE_S)
    assert bench.drive_state() is state
    assert bench.emulator.drive(NODE).connection_losses == [ConnectionLoss.HEARTBEAT]
    assert [e.code for e in bench.node.emcy.log] == [0x8130]
    if option == FAULT_SIGNAL:
        assert bench.node.sdo[0x603F].raw == 0x8130


@pytest.mark.parametrize(("command", "loss"), [
    ("STOPPED", ConnectionLoss.NMT_STOPPED),
    ("RESET COMMUNICATION", ConnectionLoss.NMT_RESET),
    ("RESET", ConnectionLoss.NMT_RESET),
])
def test_nmt_stopped_and_resets_get_the_same_reaction(bench: Bench, command: str,
                                                      loss: ConnectionLoss) -> None:
    enable_in_csp(bench, QUICK_STOP, consumer_ms=0)  # no consumer: the NMT command alone
    bench.node.nmt.state = command
    time.sleep(0.05)
    assert bench.drive_state() is PowerState.QUICK_STOP_ACTIVE
    assert bench.emulator.drive(NODE).connection_losses == [loss]
    bench.node.nmt.state = "PRE-OPERATIONAL"  # not in 0x6007's list: nothing more happens
    time.sleep(0.05)
    assert bench.emulator.drive(NODE).connection_losses == [loss]


def test_a_fault_in_nmt_stopped_sends_no_emcy(bench: Bench) -> None:
    enable_in_csp(bench, FAULT_SIGNAL, consumer_ms=0)
    bench.node.nmt.state = "STOPPED"
    time.sleep(0.05)
    assert bench.drive_state() is PowerState.FAULT
    assert bench.node.emcy.log == []


def test_the_consumer_watches_only_its_producer(bench: Bench) -> None:
    enable_in_csp(bench, QUICK_STOP)
    other = bench.network.send_periodic(0x700 + MASTER - 1, bytes([OPERATIONAL]), HEARTBEAT_S)
    heartbeat = beating(bench)
    time.sleep(0.05)
    heartbeat.stop()
    time.sleep(SILENCE_S)
    other.stop()
    assert bench.drive_state() is PowerState.QUICK_STOP_ACTIVE


def test_writing_0_to_the_consumer_disarms_it(bench: Bench) -> None:
    enable_in_csp(bench, QUICK_STOP)
    heartbeat = beating(bench)
    time.sleep(0.05)
    bench.node.sdo[0x1016][1].raw = 0
    heartbeat.stop()
    time.sleep(SILENCE_S)
    assert bench.drive_state() is PowerState.OPERATION_ENABLED
    assert bench.emulator.drive(NODE).connection_losses == []


@pytest.mark.parametrize(("index", "subindex", "value"), [
    (0x6007, 0, 4),            # reserved
    (0x6007, 0, -1),           # manufacturer-specific: this drive has none
    (0x1016, 1, 1 << 24 | MASTER << 16 | CONSUMER_MS),  # reserved bits 24-31
])
def test_values_the_drive_does_not_implement_are_refused(bench: Bench, index: int, subindex: int,
                                                         value: int) -> None:
    variable = bench.node.sdo[index] if subindex == 0 else bench.node.sdo[index][subindex]
    with pytest.raises(SdoAbortedError) as refused:
        variable.raw = value
    assert refused.value.code == SDO_VALUE_RANGE
