"""What the safety monitor's listening node hears on a CiA 402 bus, and what it makes of it.

Pure bookkeeping: frames in (COB-ID, data, the monitor's monotonic time when it read them),
one record per drive out; no bus and no clock here (``kernel/safety/canopen.py`` reads the
frames and asks the questions). What a frame means comes from CiA 301 and from the mapping
warden's driver writes to every drive (``drivers.canopen402.tables``: TPDO1 = statusword,
position actual value, torque actual value; TPDO2 = velocity actual value, modes of operation
display; the predefined connection set's COB-IDs).

A drive's NMT state is what its latest heartbeat or the latest NMT command on the bus says,
whichever came last (NMT commands are unconfirmed: the next heartbeat confirms or corrects).
Only an OPERATIONAL drive exchanges PDOs (CiA 301), so only an OPERATIONAL drive owes the
listener TPDOs; one that is PRE-OPERATIONAL or STOPPED takes no setpoint either.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum

from drivers.canopen402.tables import (
    EMCY_COB_BASE,
    EMCY_NAMES,
    HEARTBEAT_COB_BASE,
    NMT_COB_ID,
    TPDO_COB_BASE,
    TPDO_LAYOUT,
    DriveState,
    Index,
    NmtCommand,
    NmtState,
    decode_state,
    pdo_struct,
)

COMMANDED_STATE = {
    NmtCommand.START: NmtState.OPERATIONAL,
    NmtCommand.STOP: NmtState.STOPPED,
    NmtCommand.ENTER_PRE_OPERATIONAL: NmtState.PRE_OPERATIONAL,
    NmtCommand.RESET_NODE: NmtState.PRE_OPERATIONAL,
    NmtCommand.RESET_COMMUNICATION: NmtState.PRE_OPERATIONAL,
}
"""Where each NMT command leaves a drive (a reset ends in PRE-OPERATIONAL after its boot-up)."""
RESETS = frozenset({NmtCommand.RESET_NODE, NmtCommand.RESET_COMMUNICATION})
NOTABLE_STATES = frozenset({DriveState.QUICK_STOP_ACTIVE, DriveState.FAULT_REACTION_ACTIVE,
                            DriveState.FAULT})
"""402 states the monitor logs when a drive enters them: the drive is stopping on its own."""
_EMCY = struct.Struct("<HB")


class Frame(StrEnum):
    """What a frame the listener takes is, by its COB-ID."""

    NMT = "nmt"
    HEARTBEAT = "heartbeat"
    EMCY = "emcy"
    TPDO = "tpdo"


class NoticeKind(StrEnum):
    EMERGENCY = "emergency"
    DRIVE_STATE = "drive_state"


@dataclass(frozen=True, slots=True)
class Notice:
    """Something a drive said that the monitor logs (it decides nothing by it)."""

    kind: NoticeKind
    node_id: int
    detail: str


@dataclass(slots=True)
class DriveRecord:
    node_id: int
    tpdo_at: list[float | None] = field(default_factory=lambda: [None] * len(TPDO_LAYOUT))
    values: dict[Index, int] = field(default_factory=dict)
    """The last value of every object its TPDOs carry."""
    heartbeat_at: float | None = None
    """When its last heartbeat was read; None: none since it booted (or since the listener
    started), so its producer time is not known and its silence is not judged."""
    heartbeat_state: int | None = None
    nmt: NmtState | None = None
    """Its NMT state as the listener knows it; None: never heard."""
    operational_from: float | None = None
    """When it was last seen to enter OPERATIONAL: TPDOs are owed from then on."""
    state: DriveState = DriveState.UNKNOWN

    def enter(self, state: NmtState, now: float) -> None:
        if state is NmtState.OPERATIONAL and self.nmt is not NmtState.OPERATIONAL:
            self.operational_from = now
        self.nmt = state


class BusView:
    def __init__(self, drive_ids: tuple[int, ...]) -> None:
        self.drives = {node_id: DriveRecord(node_id) for node_id in drive_ids}
        self._tpdos = tuple(pdo_struct(layout) for layout in TPDO_LAYOUT)
        self._routes: dict[int, tuple[Frame, int, int]] = {NMT_COB_ID: (Frame.NMT, 0, 0)}
        for node_id in drive_ids:
            self._routes[HEARTBEAT_COB_BASE + node_id] = (Frame.HEARTBEAT, node_id, 0)
            self._routes[EMCY_COB_BASE + node_id] = (Frame.EMCY, node_id, 0)
            for number in range(len(TPDO_LAYOUT)):
                self._routes[self.tpdo_cob_id(node_id, number)] = (Frame.TPDO, node_id, number)

    @staticmethod
    def tpdo_cob_id(node_id: int, number: int) -> int:
        """COB-ID of TPDO ``number + 1`` of a drive."""
        return TPDO_COB_BASE[number] + node_id

    # -- frames in -----------------------------------------------------------------------------

    def take(self, cob_id: int, data: bytes, now: float) -> Notice | None:
        """One frame read at ``now``; anything that is not about the drives is ignored."""
        route = self._routes.get(cob_id)
        if route is None:
            return None
        kind, node_id, number = route
        if kind is Frame.NMT:
            self._nmt(data, now)
            return None
        if kind is Frame.HEARTBEAT:
            self._heartbeat(self.drives[node_id], data, now)
            return None
        if kind is Frame.EMCY:
            return _emergency(node_id, data)
        return self._tpdo(self.drives[node_id], number, data, now)

    def commanded(self, command: NmtCommand, node_id: int, now: float) -> None:
        """An NMT command sent at ``now`` to ``node_id`` (0: every node)."""
        targets = self.drives.values() if node_id == 0 else (
            [self.drives[node_id]] if node_id in self.drives else [])
        for drive in targets:
            drive.enter(COMMANDED_STATE[command], now)
            if command in RESETS:
                drive.heartbeat_at = None  # its producer time is reset with it

    def _nmt(self, data: bytes, now: float) -> None:
        if len(data) < 2:
            return
        try:
            command = NmtCommand(data[0])
        except ValueError:
            return
        self.commanded(command, data[1], now)

    def _heartbeat(self, drive: DriveRecord, data: bytes, now: float) -> None:
        if not data:
            return
        reported = data[0] & 0x7F  # bit 7 is the toggle bit of node guarding
        drive.heartbeat_state = reported
        if reported == NmtState.BOOT_UP:
            drive.heartbeat_at = None  # booted: its heartbeat producer is as configured at power-on
            drive.enter(NmtState.PRE_OPERATIONAL, now)
            return
        drive.heartbeat_at = now
        try:
            drive.enter(NmtState(reported), now)
        except ValueError:
            drive.nmt = None  # a state CiA 301 does not define: nothing is owed, nothing known

    def _tpdo(self, drive: DriveRecord, number: int, data: bytes, now: float) -> Notice | None:
        encoding = self._tpdos[number]
        if len(data) < encoding.size:
            return None  # not the mapping warden writes: never taken for data
        decoded = encoding.unpack_from(data)
        drive.values.update(zip(TPDO_LAYOUT[number], decoded, strict=True))
        drive.tpdo_at[number] = now
        if drive.nmt is None:
            drive.enter(NmtState.OPERATIONAL, now)  # only an OPERATIONAL node sends PDOs
        if Index.STATUSWORD not in TPDO_LAYOUT[number]:
            return None
        state = decode_state(drive.values[Index.STATUSWORD])
        previous, drive.state = drive.state, state
        if state is not previous and state in NOTABLE_STATES:
            return Notice(NoticeKind.DRIVE_STATE, drive.node_id, f"entered {state}")
        return None

    # -- questions -----------------------------------------------------------------------------

    def lost(self, now: float, device_timeout_s: float, heartbeat_timeout_s: float,
             label: Callable[[int], str] = str) -> str | None:
        """Why the listener has lost a drive, or None: a heartbeat that stopped, or an
        OPERATIONAL drive whose TPDOs stopped (``label`` names a drive by its node id)."""
        for drive in self.drives.values():
            if drive.heartbeat_at is not None and now - drive.heartbeat_at > heartbeat_timeout_s:
                return (f"{label(drive.node_id)}: no heartbeat for "
                        f"{(now - drive.heartbeat_at) * 1e3:.0f} ms (heartbeat_timeout_ms "
                        f"{heartbeat_timeout_s * 1e3:g})")
            silent = self._silent_tpdo(drive, now, device_timeout_s)
            if silent is not None:
                number, age = silent
                return (f"{label(drive.node_id)} is OPERATIONAL but sent no TPDO{number + 1} "
                        f"(COB-ID 0x{self.tpdo_cob_id(drive.node_id, number):03X}) for "
                        f"{age * 1e3:.0f} ms (device_timeout_ms {device_timeout_s * 1e3:g}): "
                        "nobody sends SYNC, or the drive stopped answering")
        return None

    def _silent_tpdo(self, drive: DriveRecord, now: float,
                     timeout_s: float) -> tuple[int, float] | None:
        if drive.nmt is not NmtState.OPERATIONAL or drive.operational_from is None:
            return None
        for number, at in enumerate(drive.tpdo_at):
            since = drive.operational_from if at is None else max(at, drive.operational_from)
            if now - since > timeout_s:
                return number, now - since
        return None

    def process_data(self, node_ids: tuple[int, ...]) -> list[dict[Index, int]] | None:
        """Each drive's TPDO values, if every one of them is OPERATIONAL and has sent every
        TPDO since it became so; None otherwise (it takes no setpoint, or has not answered a
        SYNC yet)."""
        found = []
        for node_id in node_ids:
            drive = self.drives[node_id]
            start = drive.operational_from
            if drive.nmt is not NmtState.OPERATIONAL or start is None or any(
                    at is None or at < start for at in drive.tpdo_at):
                return None
            found.append(drive.values)
        return found

    def not_stopped_since(self, since: float) -> list[int]:
        """Drives no heartbeat of which has reported STOPPED after ``since``."""
        return [drive.node_id for drive in self.drives.values()
                if not (drive.heartbeat_at is not None and drive.heartbeat_at >= since
                        and drive.heartbeat_state == NmtState.STOPPED)]


def _emergency(node_id: int, data: bytes) -> Notice | None:
    if len(data) < _EMCY.size:
        return None
    code, register = _EMCY.unpack_from(data)
    if code & 0xFF00 == 0:
        detail = "error reset (EMCY 0x0000): no error left"
    else:
        name = EMCY_NAMES.get(code, "see the drive's manual")
        detail = f"EMCY 0x{code:04X} ({name}), error register 0x{register:02X}"
    return Notice(NoticeKind.EMERGENCY, node_id, detail)
