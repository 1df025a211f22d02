"""The drives' watchdog on warden: warden's heartbeat, and each drive's consumer of it.

CiA 301 lets a node watch another's heartbeat (0x1016, consumer heartbeat time: producer node id
and a time in ms); CiA 402-2 says what a drive does when such a heartbeat event occurs, or NMT
STOPPED or a reset, or bus-off (0x6007, abort connection option code). So warden produces a
heartbeat of its own (COB-ID 0x700 + ``master_node_id``, NMT state OPERATIONAL) and every drive
consumes it:

- The heartbeat goes out from the control loop, not from a timer thread: with every write (any
  command, refused ones too), at most every ``master_heartbeat_ms``, and while a blocking step
  of the driver runs (the loop waits for it and beats meanwhile). A loop that stops writing,
  hangs or dies stops it; the bus cycle's keeper thread, which goes on sending SYNC when the
  loop is late, does not send it.
- 0x6007 is written at connect (before anything is armed): QUICK STOP for the joints, so that
  they ramp down and hold, powered, in QUICK STOP ACTIVE (0x605A = 6 is the driver's quick stop
  option); NO ACTION for the gripper, which keeps squeezing a held part, as a STOP leaves it.
  At connect each drive's consumer entry is also cleared, in case a killed run left it armed.
- The consumer entry (sub-index 1) is armed right before the loop's first tick (the driver's
  ``before_first_tick``), or by the first position setpoint after activation for a caller
  without that hook: armed at activation, the drives would stop while the kernel starts the
  policy server, about a second before its first tick; armed inside the first tick, its SDO
  round trips stalled it. A drive watches the heartbeat from the first one it hears.
- It is disarmed (0) on deactivate, before the drives are disabled.

The SDO steps run on the device thread; :class:`MasterHeartbeat` only sends frames;
:class:`DriveWatchdog` is the driver's record of where the watchdog stands.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator

import can

from drivers.base import DriverIOError
from drivers.canopen402._sdk import Network, Node402
from drivers.canopen402.settings import CiA402Settings
from drivers.canopen402.tables import HEARTBEAT_COB_BASE, AbortConnection, Index, NmtState

CONSUMER_ENTRY = 1
"""The sub-index of 0x1016 warden uses: the first (a drive has at least one)."""
JOINT_REACTION = AbortConnection.QUICK_STOP
GRIPPER_REACTION = AbortConnection.NO_ACTION


def consumer_entry(master_node_id: int, timeout_ms: int) -> int:
    """0x1016 sub-index value: bits 16-23 the producer's node id, bits 0-15 the time in ms."""
    return master_node_id << 16 | timeout_ms


def prepare(node: Node402, reaction: AbortConnection) -> None:
    """At connect: the reaction to a lost connection, and no consumer armed (device thread)."""
    node.sdo[Index.ABORT_CONNECTION_OPTION].raw = reaction
    disarm(node)


def prepare_all(nodes: tuple[Node402, ...], settings: CiA402Settings) -> None:
    """``prepare`` every drive, the gripper with its own reaction; nothing if switched off
    (a drive without 0x1016 or 0x6007 then works as before)."""
    if not settings.watchdog_ms:
        return
    for node in nodes:
        prepare(node, GRIPPER_REACTION if node.id == settings.gripper_node else JOINT_REACTION)


def arm(node: Node402, entry: int) -> None:
    node.sdo[Index.HEARTBEAT_CONSUMER][CONSUMER_ENTRY].raw = entry


def disarm(node: Node402) -> None:
    node.sdo[Index.HEARTBEAT_CONSUMER][CONSUMER_ENTRY].raw = 0


class MasterHeartbeat:
    """warden's heartbeat frame, sent only when the driver says so."""

    def __init__(self, network: Network, master_node_id: int, producer_time_s: float) -> None:
        self._network = network
        self._cob_id = HEARTBEAT_COB_BASE + master_node_id
        self.producer_time_s = producer_time_s
        self._last = -float("inf")
        self.sent = 0

    def beat(self) -> None:
        """Send it if the producer time has passed since the last one.

        Raises:
            can.CanError: the bus refused the frame.
        """
        now = time.monotonic()
        if now - self._last < self.producer_time_s:
            return
        self._network.send_message(self._cob_id, bytes([NmtState.OPERATIONAL]))
        self._last = now
        self.sent += 1

    @contextlib.asynccontextmanager
    async def kept_up(self) -> AsyncIterator[None]:
        """Beat from the event loop while the block runs (a blocking step on the device
        thread: the loop is alive, only waiting)."""
        task = asyncio.get_running_loop().create_task(self._keep_beating())
        try:
            yield
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    async def _keep_beating(self) -> None:
        while True:
            try:
                self.beat()
            except can.CanError:
                return  # the blocking step on the same bus reports it; beating stops here
            await asyncio.sleep(self.producer_time_s)


class DriveWatchdog:
    """Where the drives' watchdog stands, for the driver: off, waiting for the first setpoint,
    or armed (then every write beats, and so does the loop while a blocking step runs)."""

    def __init__(self, settings: CiA402Settings) -> None:
        self.settings = settings
        self.heartbeat: MasterHeartbeat | None = None
        self.armed = False

    def attach(self, network: Network) -> None:
        self.heartbeat = MasterHeartbeat(network, self.settings.master_node_id,
                                         self.settings.master_heartbeat_ms / 1000.0)

    @property
    def to_arm(self) -> bool:
        return bool(self.settings.watchdog_ms) and not self.armed

    @property
    def entry(self) -> int:
        return consumer_entry(self.settings.master_node_id, self.settings.watchdog_ms)

    def beat(self) -> None:
        """Raises:
        DriverIOError: the bus refused the heartbeat (LINK_LOST)."""
        if not (self.armed and self.heartbeat is not None):
            return
        try:
            self.heartbeat.beat()
        except can.CanError as error:
            raise DriverIOError(self.settings.name, f"sending warden's heartbeat on "
                                f"{self.settings.describe_bus()} failed: {error}") from error

    def kept_up(self) -> contextlib.AbstractAsyncContextManager[None]:
        """Beat while a blocking step runs, if armed."""
        if self.armed and self.heartbeat is not None:
            return self.heartbeat.kept_up()
        return contextlib.nullcontext()
