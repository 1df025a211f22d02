"""Loopback by default: every emulator, the reference policy server and a running cell keep
their sockets on this host, and the emulated CANopen bus takes no frame from the network.

The sockets are listed from the kernel (``ss``) for the process and its children; a socket is
host-local when it is bound to a loopback address or to the loopback device (the udp_multicast
buses: bound to every address, but only to ``lo``). "From the network" is this host's own
address on its network interface: a datagram sent from it, to the bus's multicast group or to
that address and the bus's port, arrives on that interface, as another host's would.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable

import can
import pytest
from can.interfaces.udp_multicast.utils import pack_message

from drivers.canopen402.settings import CiA402Settings
from drivers.canopen402.udp_bus import confine_to_host as confine_drivers_bus
from drivers.settings import SettingsError
from stubs.cia402_drive.launch import unique_udp_bus
from stubs.cia402_drive.udp_bus import confine_to_host as confine_emulators_bus
from stubs.fault_control import inject
from stubs.process import EmulatorProcess
from stubs.ur_controller.launch import free_loopback_host
from tests.cell.harness import DRIVER_MANIFESTS, DriverCycle, SimCycle
from tests.net import OpenSocket, inet_sockets, own_non_loopback_address, process_tree

NMT_START_ALL = pack_message(can.Message(arbitration_id=0x000, data=[0x01, 0x00],
                                         is_extended_id=False))
"""NMT "start remote node" to every node: what a stray host could send the drives."""


def _emulators() -> dict[str, Callable[[], tuple[str, ...]]]:
    def canopen() -> tuple[str, ...]:
        group, port = unique_udp_bus()
        return ("stubs.cia402_drive", "--channel", group, "--port", str(port), "--nodes", "1,2")

    return {
        "ur_controller": lambda: ("stubs.ur_controller", "--host", free_loopback_host()),
        "dynamixel_bus": lambda: ("stubs.dynamixel_bus", "--ids", "1,2"),
        "cia402_drive": canopen,
        "policy_server": lambda: ("stubs.policy_server", "--port", "0"),
    }


def _not_local(sockets: list[OpenSocket]) -> list[OpenSocket]:
    return [s for s in sockets if not s.host_local]


@pytest.mark.parametrize("name", list(_emulators()))
def test_each_emulator_and_the_reference_server_bind_loopback_only(name: str) -> None:
    with EmulatorProcess(*_emulators()[name]()) as process:
        sockets = inet_sockets(process_tree(process.pid))
    assert sockets, f"{name}: no socket found: the listing does not see the process"
    assert _not_local(sockets) == []


def _send_from(address: str, interface: str, datagram: bytes,
               *destinations: tuple[str, int]) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        sender.bind((address, 0))
        sender.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(interface))
        sender.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
        for destination in destinations:
            sender.sendto(datagram, destination)


def test_the_drive_emulator_takes_no_nmt_command_from_the_network() -> None:
    outside = own_non_loopback_address()
    group, port = unique_udp_bus()
    args = ("--channel", group, "--port", str(port), "--nodes", "1,2")
    with EmulatorProcess("stubs.cia402_drive", *args) as emulator:
        control = ("127.0.0.1", int(emulator.info["fault_port"]))

        def states() -> set[str]:
            return {drive["nmt"] for drive in inject(control, "drives")["drives"].values()}

        assert states() == {"PRE-OPERATIONAL"}
        _send_from(outside, outside, NMT_START_ALL, (group, port), (outside, port))
        time.sleep(0.5)  # time enough for a frame that got in to be handled
        assert states() == {"PRE-OPERATIONAL"}, "a frame from the network reached the drives"
        # The same frame sent on this host reaches them: the check above can fail.
        _send_from("127.0.0.1", "127.0.0.1", NMT_START_ALL, (group, port))
        deadline = time.monotonic() + 5.0
        while states() != {"OPERATIONAL"} and time.monotonic() < deadline:
            time.sleep(0.05)
        assert states() == {"OPERATIONAL"}


def test_warden_s_udp_bus_takes_no_frame_from_the_network() -> None:
    outside = own_non_loopback_address()
    group, port = unique_udp_bus()
    frame = can.Message(arbitration_id=0x181, data=[1, 2, 3], is_extended_id=False)
    warden = can.Bus(interface="udp_multicast", channel=group, port=port)
    drives = can.Bus(interface="udp_multicast", channel=group, port=port)
    try:
        confine_drivers_bus(warden, group)
        confine_emulators_bus(drives, group)
        _send_from(outside, outside, pack_message(frame), (group, port), (outside, port))
        assert warden.recv(timeout=0.5) is None, "a frame from the network reached warden"
        drives.send(frame)  # the emulator's side, on this host
        received = warden.recv(timeout=5.0)
        assert received is not None and received.arbitration_id == 0x181
        assert warden.recv(timeout=0.2) is None  # exactly one delivery (TTL 0, loop copy)
    finally:
        warden.shutdown()
        drives.shutdown()


@pytest.mark.parametrize("channel", ["ff15::1", "10.0.0.1", "can0"])
def test_a_udp_multicast_channel_is_an_ipv4_group(channel: str) -> None:
    table = {"interface": "udp_multicast", "channel": channel, "node_ids": [1],
             "counts_per_rev": [4096]}
    with pytest.raises(SettingsError, match=r"channel: .* (not an IPv4 multicast group|not an "
                                            r"IP address)"):
        CiA402Settings.from_mapping(table)
    assert CiA402Settings.from_mapping({**table, "channel": "239.1.2.3"}).channel == "239.1.2.3"


def _running_cells_sockets(name: str, sim_cycle: SimCycle,
                           driver_cycle: Callable[[str], DriverCycle]) -> list[OpenSocket]:
    """The sockets a whole cycle had open 200 ticks in (tests/cell/conftest.py's runs, shared
    with test_live_cell.py and test_driver_cells.py)."""
    return driver_cycle(name).sockets if name in DRIVER_MANIFESTS else sim_cycle.sockets


@pytest.mark.slow
@pytest.mark.parametrize("name", ["sim-ur5e.toml", *DRIVER_MANIFESTS])
def test_a_running_cell_keeps_every_socket_on_this_host(
        name: str, sim_cycle: SimCycle, driver_cycle: Callable[[str], DriverCycle]) -> None:
    sockets = _running_cells_sockets(name, sim_cycle, driver_cycle)
    assert sockets, "the run ended before the sockets were listed"
    assert _not_local(sockets) == []
    kinds = {(s.protocol, s.state) for s in sockets}
    assert ("tcp", "ESTAB") in kinds  # the policy link, at least
    if name == "sim-canopen.toml":  # warden's bus and the emulator's, both on lo only
        udp = [s for s in sockets if s.protocol == "udp"]
        assert len({s.pid for s in udp}) >= 2 and all("%lo:" in s.local for s in udp)
