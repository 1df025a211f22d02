"""What the drives say about themselves between calls: heartbeats, EMCYs, TPDO arrivals.

canopen calls the ``_on_*`` callbacks from whichever thread dispatches frames (the event loop or
the notifier's reader thread); the driver reads the result from the loop and the device thread.
A lock keeps each node's record consistent. ``check`` turns the record into the error the
lifecycle needs: an EMCY is a CONTROLLER_FAULT (but a heartbeat error, the drive's watchdog on
warden, is a WATCHDOG), a silent drive is LINK_LOST, a drive that is alive but stopped sending
process data is a WATCHDOG.
"""

from __future__ import annotations

import functools
import threading
import time
from dataclasses import dataclass, field

from assurance.reasons import ReasonCode
from drivers.base import DeviceFault, DriverIOError, DriverTimeout
from drivers.canopen402._sdk import EmcyEntry, Node402
from drivers.canopen402.settings import CiA402Settings
from drivers.canopen402.tables import EMCY_HEARTBEAT, EMCY_NAMES, NmtState


@dataclass(frozen=True, slots=True)
class EmcyRecord:
    code: int
    register: int
    description: str

    def describe(self) -> str:
        return f"EMCY 0x{self.code:04X} ({self.description}), error register 0x{self.register:02X}"


@dataclass(slots=True)
class NodeRecord:
    heartbeat_at: float | None = None
    nmt_state: int | None = None
    tpdo_at: float | None = None
    emcy: list[EmcyRecord] = field(default_factory=list)
    heard: threading.Condition = field(default_factory=threading.Condition)


class HealthMonitor:
    def __init__(self, settings: CiA402Settings) -> None:
        self._settings = settings
        self._records = {node_id: NodeRecord() for node_id in settings.drive_ids}

    def attach(self, node: Node402) -> None:
        node.nmt.add_heartbeat_callback(functools.partial(self._on_heartbeat, node.id))
        node.emcy.add_callback(functools.partial(self._on_emcy, node.id))

    # -- callbacks (frame dispatch thread) -----------------------------------------------------

    def _on_heartbeat(self, node_id: int, state: int) -> None:
        record = self._records[node_id]
        with record.heard:
            record.heartbeat_at = time.monotonic()
            record.nmt_state = state
            record.heard.notify_all()

    def _on_emcy(self, node_id: int, entry: EmcyEntry) -> None:
        if entry.code & 0xFF00 == 0:
            return  # "error reset / no error": the drive clearing its own fault, not a new one
        description = EMCY_NAMES.get(entry.code) or entry.get_desc() or "unknown"
        record = self._records[node_id]
        with record.heard:
            record.emcy.append(EmcyRecord(entry.code, entry.register, description))

    def on_tpdo(self, node_id: int) -> None:
        self._records[node_id].tpdo_at = time.monotonic()

    # -- waits (device thread only: they block) ------------------------------------------------

    def wait_heartbeat(self, node_id: int, since: float, timeout_s: float,
                       state: NmtState | None = None) -> bool:
        """Block until a heartbeat sent after ``since`` (monotonic) is in (in ``state``)."""
        record = self._records[node_id]
        deadline = time.monotonic() + timeout_s
        with record.heard:
            while True:
                fresh = record.heartbeat_at is not None and record.heartbeat_at >= since
                if fresh and (state is None or record.nmt_state == state):
                    return True
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                record.heard.wait(remaining)

    def clear_emcy(self, node_id: int) -> None:
        record = self._records[node_id]
        with record.heard:
            record.emcy.clear()

    def first_emcy(self, node_id: int) -> EmcyRecord | None:
        record = self._records[node_id]
        with record.heard:
            return record.emcy[0] if record.emcy else None

    # -- the check every read and write makes --------------------------------------------------

    def check(self, expect_pdos: bool) -> None:
        """Raise the first problem any drive has.

        Raises:
            DeviceFault: a drive sent an EMCY (CONTROLLER_FAULT).
            DriverIOError: a drive's heartbeat stopped or left OPERATIONAL (LINK_LOST).
            DriverTimeout: a drive's heartbeat is fine but its TPDOs stopped (WATCHDOG).
        """
        now = time.monotonic()
        for node_id, record in self._records.items():
            if record.emcy:
                self._raise_emcy(node_id, record.emcy[0])
            self._check_heartbeat(node_id, record, now, expect_pdos)
            if expect_pdos:
                self._check_tpdo(node_id, record, now)

    def _label(self, node_id: int) -> str:
        return self._settings.node_label(node_id)

    def _raise_emcy(self, node_id: int, emcy: EmcyRecord) -> None:
        if emcy.code == EMCY_HEARTBEAT:
            raise DeviceFault(
                self._settings.name, f"{self._label(node_id)} reports {emcy.describe()}: its "
                f"watchdog missed warden's heartbeat for {self._settings.watchdog_ms} ms and "
                "reacted as its 0x6007 says", ReasonCode.WATCHDOG)
        raise DeviceFault(self._settings.name, f"{self._label(node_id)} reports {emcy.describe()}",
                          ReasonCode.CONTROLLER_FAULT)

    def _check_heartbeat(self, node_id: int, record: NodeRecord, now: float,
                         expect_pdos: bool) -> None:
        timeout_s = self._settings.heartbeat_timeout_ms / 1000.0
        if record.heartbeat_at is None or now - record.heartbeat_at > timeout_s:
            silent = "never" if record.heartbeat_at is None else (
                f"not for {1000 * (now - record.heartbeat_at):.0f} ms")
            raise DriverIOError(
                self._settings.name, f"{self._label(node_id)} heartbeat lost: heard {silent} "
                f"(consumer timeout {self._settings.heartbeat_timeout_ms} ms) on "
                f"{self._settings.describe_bus()}",
            )
        if expect_pdos and record.nmt_state != NmtState.OPERATIONAL:
            raise DriverIOError(
                self._settings.name, f"{self._label(node_id)} left OPERATIONAL: its heartbeat "
                f"reports NMT state {record.nmt_state}, so it no longer exchanges process data",
            )

    def _check_tpdo(self, node_id: int, record: NodeRecord, now: float) -> None:
        timeout_s = self._settings.tpdo_timeout_ms / 1000.0
        if record.tpdo_at is not None and now - record.tpdo_at <= timeout_s:
            return
        silent = "never" if record.tpdo_at is None else f"{1000 * (now - record.tpdo_at):.0f} ms"
        heartbeat_age = now - (record.heartbeat_at or 0.0)
        if heartbeat_age > 2 * self._settings.heartbeat_period_ms / 1000.0:
            # Both streams stopped: a dead drive or cable, which is the link, not a late reply.
            raise DriverIOError(
                self._settings.name, f"{self._label(node_id)} went silent: no TPDO for {silent} "
                f"and no heartbeat for {1000 * heartbeat_age:.0f} ms on "
                f"{self._settings.describe_bus()}",
            )
        raise DriverTimeout(
            self._settings.name, f"{self._label(node_id)} sent no TPDO for {silent} (timeout "
            f"{self._settings.tpdo_timeout_ms} ms) although its heartbeat is alive",
        )
