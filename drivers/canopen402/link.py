"""Open and close the CAN bus, the canopen network and one ``BaseNode402`` per drive (every
joint, then the gripper if the settings name one).

The one place that constructs vendor objects. Received frames reach canopen through a python-can
``Notifier``: bound to the event loop when the bus has a file descriptor (``udp_multicast``,
``socketcan``), so frames are dispatched by the loop with no reader thread; on ``virtual``, which
has none, a reader thread dispatches them (binding it to the loop would only add a
``call_soon_threadsafe`` hop per frame).
"""

from __future__ import annotations

import asyncio
import copy
import functools
import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import can
import canopen
from canopen.objectdictionary import ODVariable

from drivers.base import DriverInitError
from drivers.canopen402._sdk import CanBus, Network, Node402, Notifier
from drivers.canopen402.settings import CiA402Settings
from drivers.canopen402.tables import DEFAULT_EDS, Controlword
from drivers.canopen402.udp_bus import confine_to_host, widen_receive_buffer

log = logging.getLogger(__name__)

NOTIFIER_POLL_S = 0.05
"""Reader-thread receive timeout: bounds how long closing waits for the thread to notice."""
CATCH_UP_LIMIT = 20_000
"""Most frames one catch-up hands over: some seconds of a busy bus, so it always ends."""


@dataclass(slots=True)
class Link:
    settings: CiA402Settings
    bus: CanBus
    network: Network
    nodes: tuple[Node402, ...]
    """Every drive: the joints in joint order, then the gripper (``settings.drive_ids``)."""
    notifier: Notifier | None = None
    loop_bound: bool = False
    """True when the notifier runs on the event loop (it must then be stopped there too)."""

    @property
    def joints(self) -> tuple[Node402, ...]:
        return self.nodes[: len(self.settings.node_ids)]

    @property
    def gripper(self) -> Node402 | None:
        return self.nodes[-1] if self.settings.gripper_node is not None else None

    def start_notifier(self, loop: asyncio.AbstractEventLoop) -> None:
        """Start dispatching received frames. Call on the loop thread (``add_reader``)."""
        try:
            fd = self.bus.fileno()
        except NotImplementedError:
            fd = -1
        self.loop_bound = fd >= 0
        self.notifier = can.Notifier(
            cast(can.BusABC, self.bus), self.network.listeners, timeout=NOTIFIER_POLL_S,
            loop=loop if self.loop_bound else None,
        )
        self.network.notifier = self.notifier

    def catch_up(self) -> int:
        """Hand every frame already received to the listeners now; returns how many there were.

        A notifier on the event loop dispatches one frame per loop iteration, so after a call
        that held the loop up (an application's blocking start-up step, a long GC pass) frames
        that arrived in time can still be waiting, and a drive that kept talking would look
        silent. Call on the loop thread. A reader thread keeps up by itself: nothing to do.
        """
        if not self.loop_bound or self.notifier is None:
            return 0
        count = 0
        while count < CATCH_UP_LIMIT and (message := self.bus.recv(0)) is not None:
            for listener in self.notifier.listeners:
                listener(message)
            count += 1
        return count

    def quick_stop(self, send: Callable[[], object]) -> None:
        """Quick-stop every drive and ``send`` one last bus cycle; best effort (on the way out)."""
        try:
            for node in self.nodes:
                node.controlword = Controlword.QUICK_STOP
            send()
        except (can.CanError, RuntimeError):
            pass  # the link is already gone: nothing more reaches the drives from here

    async def aclose(self) -> None:
        """NMT pre-operational for every drive (best effort), then :meth:`close`."""
        try:
            for node in self.nodes:
                node.nmt.state = "PRE-OPERATIONAL"
        except (can.CanError, RuntimeError):
            pass  # best effort: closing goes on
        if self.loop_bound:
            self.close()  # its reader is an fd on this loop: remove it here
        else:
            await asyncio.to_thread(self.close)

    def close(self) -> None:
        """Stop the notifier and release the bus; never raises (it runs on the way out)."""
        try:
            if self.notifier is not None:
                self.notifier.stop(timeout=1.0)
        except Exception:  # closing must go on; the bus below is what matters
            log.exception("%s: stopping the CAN notifier failed", self.settings.name)
        finally:
            self.network.notifier = None
            self.network.bus = None
            self.bus.shutdown()


def build_link(settings: CiA402Settings) -> Link:
    """Open the bus and describe every drive; blocking, so it runs on the device thread.

    Raises:
        DriverInitError: unknown interface, unreadable EDS, or a bus that does not open.
    """
    eds = _eds_path(settings)
    bus = open_bus(settings)
    try:
        network = cast(Network, canopen.Network(bus))
        nodes = tuple(_add_node(network, node_id, eds, settings)
                      for node_id in settings.drive_ids)
    except Exception as error:
        bus.shutdown()
        raise DriverInitError(settings.name, f"cannot load the object dictionary {eds}: "
                              f"{error}") from error
    return Link(settings, cast(CanBus, bus), network, nodes)


def open_bus(settings: CiA402Settings) -> can.BusABC:
    """The CAN bus the settings name, opened as the driver opens it: receive buffer widened, and
    a ``udp_multicast`` simulation bus kept on this host (``udp_bus.confine_to_host``).

    The one way warden's processes open this bus: the driver here, and the safety monitor's
    listening node (``kernel/safety/canopen.py``), which must reach the very bus warden's
    drives are on.

    Raises:
        DriverInitError: unknown interface, or a bus that does not open or cannot be kept on
            this host.
    """
    _check_interface(settings)
    bus = _open_bus(settings)
    try:
        widen_receive_buffer(cast(CanBus, bus))
        if settings.interface == "udp_multicast":
            confine_to_host(cast(CanBus, bus), settings.channel)
    except (OSError, ValueError) as error:
        bus.shutdown()
        raise DriverInitError(settings.name, f"cannot keep the udp_multicast bus on this host "
                              f"({settings.describe_bus()}): {error}") from error
    return bus


def _check_interface(settings: CiA402Settings) -> None:
    if settings.interface not in can.interfaces.VALID_INTERFACES:
        known = ", ".join(sorted(can.interfaces.VALID_INTERFACES))
        raise DriverInitError(
            settings.name, f"unknown CAN interface {settings.interface!r} (python-can knows: "
            f"{known}); check 'interface' in the manifest",
        )


def _eds_path(settings: CiA402Settings) -> Path:
    eds = Path(settings.eds_path) if settings.eds_path else DEFAULT_EDS
    if not eds.is_file():
        raise DriverInitError(settings.name, f"EDS file {eds} does not exist; check 'eds_path'")
    return eds


def _open_bus(settings: CiA402Settings) -> can.BusABC:
    try:
        return can.Bus(interface=settings.interface, channel=settings.channel,
                       **settings.bus_options())
    except (can.CanError, OSError, ValueError, ImportError) as error:
        raise DriverInitError(
            settings.name, f"cannot open the CAN bus ({settings.describe_bus()}): {error}; check "
            "that the interface exists and is up, and the channel name",
        ) from error


def load_object_dictionary(eds: Path, node_id: int = 0) -> canopen.ObjectDictionary:
    """A private copy of the parsed EDS, with ``$NODEID`` defaults (COB-IDs) for ``node_id``.

    Parsing costs ~35 ms, so each file is parsed once, for node id 0, and each copy adds its
    node id to the defaults canopen marks as relative.
    """
    od = copy.deepcopy(_parse_eds(str(eds), eds.stat().st_mtime_ns))
    if node_id:
        for variable in _variables(od):
            if variable.relative and isinstance(variable.default, int):
                variable.default += node_id
    return od


@functools.lru_cache(maxsize=8)
def _parse_eds(path: str, mtime_ns: int) -> canopen.ObjectDictionary:
    return canopen.import_od(path, 0)


def _variables(od: canopen.ObjectDictionary) -> Iterator[ODVariable]:
    for entry in od.values():
        if isinstance(entry, ODVariable):
            yield entry
        else:
            yield from (v for v in entry.values() if isinstance(v, ODVariable))


def _add_node(network: Network, node_id: int, eds: Path, settings: CiA402Settings) -> Node402:
    node = cast(Node402, canopen.BaseNode402(node_id, load_object_dictionary(eds, node_id)))
    node.sdo.RESPONSE_TIMEOUT = settings.sdo_timeout_s
    return network.add_node(node)
