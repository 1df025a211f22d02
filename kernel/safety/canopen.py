"""The monitor's watch on CiA 402 drives (driver ``canopen402``): a listening node on their bus.

Its own connection: a second node on the drives' CAN bus, opened with the driver's own
``open_bus`` (the interface, channel and options of the manifest's ``[driver]`` table, opened the
way warden's driver opens them), so it hears what every node on that bus hears. It only listens:
it sends no SDO (a drive's SDO server is warden's driver's), no PDO (the RPDOs' COB-IDs are
warden's, and a second producer of one COB-ID would collide on the wire), no SYNC, no NMT start
and no heartbeat. It is not the NMT master; the one frame it sends is its stop.

What it reads (:mod:`kernel.safety.canopen_view`): each drive's TPDO1 (statusword, position
actual value, torque actual value) and TPDO2 (velocity actual value, modes of operation
display), the mapping warden's driver writes to every drive at configure over SDO
(``drivers.canopen402.tables.TPDO_LAYOUT``; COB-IDs 0x180/0x280 + node id, the predefined
connection set the driver keeps), each drive's heartbeat (its NMT state), its EMCYs (logged), and
the NMT commands on the bus. Positions and velocities become radians with the manifest's
calibration through the driver's ``JointScale`` (``q = direction × (counts − offset_counts) ×
2π / counts_per_rev``). There is no force: a CiA 402 cell has no wrist sensor on this bus.

What it takes from the driver is data and arithmetic: its settings class (the ``[driver]`` table
checked as the driver checks it), ``open_bus``, the mapping constants and the unit conversion.
None of the driver's control code (bring-up, bus cycle, 402 state changes, watchdog) runs here:
a mistake in how warden commands the drives is not repeated in how the monitor watches them.

Stop path: NMT *Stop remote node* (COB-ID 0x000, command 0x02) to each drive of the manifest,
joints first. A STOPPED node exchanges no PDO (CiA 301), so warden's setpoints no longer reach
it until an NMT start, which only warden's driver sends, at its configure; and entering STOPPED
is a lost connection for CiA 402 (0x6007), which warden's driver sets to quick stop on the
joints and no action on the gripper (it keeps its grip). A controlword quick stop is not used:
written by RPDO it would be a second producer of warden's COB-ID, by SDO it would race warden's
SDO transfers, and either way warden's next RPDO (ENABLE OPERATION) takes a drive out of QUICK
STOP ACTIVE again (transition 16, allowed by warden's 0x605A = 6). docs/operations.md, "Safety
monitor", has the reasoning, the bound and what was measured.
"""

from __future__ import annotations

import time

import can
import structlog

from drivers.base import DriverInitError
from drivers.canopen402.link import open_bus
from drivers.canopen402.settings import CiA402Settings
from drivers.canopen402.tables import NMT_COB_ID, Index, NmtCommand
from kernel.safety.canopen_view import BusView, Notice, NoticeKind
from kernel.safety.checks import Sample
from kernel.safety.settings import SafetySettings
from kernel.safety.view import MonitorView
from kernel.safety.watch import DeviceLost, DeviceUnreachable, StopResult

log = structlog.get_logger("warden.safety")
DRAIN_LIMIT = 20_000
"""Most frames one read takes: seconds of a busy bus, so a read always ends."""
SEND_TIMEOUT_S = 0.05


class CiA402Watch:
    can_stop = True
    lives_in_warden = False

    def __init__(self, settings: CiA402Settings, safety: SafetySettings) -> None:
        self.settings = settings
        self.device_timeout_s = safety.device_timeout_ms / 1e3
        self.heartbeat_timeout_s = settings.heartbeat_timeout_ms / 1e3
        # A stop is confirmed by each drive's STOPPED heartbeat, awaited as long as silence is
        # not yet a loss: a heartbeat late on a loaded host still confirms it.
        self.confirm_s = self.heartbeat_timeout_s
        ids = ", ".join(map(str, settings.drive_ids))
        self.description = (f"CiA 402 drives {ids} on {settings.describe_bus()} (own listening "
                            "node: TPDOs, heartbeats, EMCY)")
        self.stop_path = (f"NMT stop remote node to drives {ids}: the joints quick-stop "
                          "(0x6007 = 3, written by warden's driver), the gripper keeps its grip")
        self._scales = settings.joint_scales()
        self._view = BusView(settings.drive_ids)
        self._bus: can.BusABC | None = None
        self._bus_problem: str | None = None
        self._read_empty_at = time.monotonic()

    @classmethod
    def from_manifest(cls, manifest: MonitorView, safety: SafetySettings) -> CiA402Watch:
        """Raises:
            DeviceUnreachable: the manifest does not name the bus, or does not make the drives
                quick-stop on NMT STOPPED.
        """
        where = f"{manifest.path}: driver"
        if manifest.emulator.launch:
            raise DeviceUnreachable(
                f"{manifest.path}: emulator.launch: true, so warden picks the emulated drives' "
                "bus when it starts them and the monitor cannot know it; start the emulator "
                "yourself (python -m stubs.cia402_drive), name its bus in [driver] (interface, "
                "channel, udp_port) and set launch = false")
        settings: CiA402Settings = manifest.driver_settings  # checked when it was loaded
        if not settings.watchdog_ms:
            raise DeviceUnreachable(
                f"{where}.watchdog_ms: 0, so warden's driver leaves each drive's abort "
                "connection option code (0x6007) as the drive has it, and what the monitor's "
                "NMT stop makes a drive do is not known; the monitor needs the quick stop the "
                "driver writes with its watchdog (watchdog_ms > 0)")
        return cls(settings, safety)

    # -- the DeviceWatch interface -------------------------------------------------------------

    def connect(self) -> None:
        """Open the bus. Nothing is asked of the drives: at power-on they may be silent (their
        heartbeat starts when warden's driver sets 0x1017), and NMT has no answer to probe."""
        try:
            self._bus = open_bus(self.settings)
        except DriverInitError as error:
            raise DeviceUnreachable(f"{error}; check interface and channel in [driver]"
                                    ) from error
        self._bus_problem = None
        self._read_empty_at = time.monotonic()

    def sample(self) -> Sample | None:
        """The joints from the drives' latest TPDOs; None while they exchange no process data
        (not OPERATIONAL, or not heard since the monitor started): then they take no setpoint.

        Raises:
            DeviceLost: the bus fails, a drive's heartbeat stopped, or an OPERATIONAL drive
                sent no TPDO for ``device_timeout_ms``.
        """
        self._drain()
        problem = self._lost(time.monotonic())
        if problem is not None:
            raise DeviceLost(problem)
        values = self._view.process_data(self.settings.node_ids)
        if values is None:
            return None
        return Sample(
            q=tuple(scale.to_rad(v[Index.POSITION_ACTUAL])
                    for scale, v in zip(self._scales, values, strict=True)),
            qd=tuple(scale.velocity_to_rad(v[Index.VELOCITY_ACTUAL])
                     for scale, v in zip(self._scales, values, strict=True)),
            force_n=None)

    def stop(self) -> StopResult:
        """NMT stop to every drive, then up to ``confirm_s`` for each one's heartbeat to say
        STOPPED (done only then: NMT itself is never acknowledged)."""
        if self._bus is None or self._bus_problem is not None:
            self.close()  # a bus that failed is opened again: the stop may get through
            try:
                self.connect()
            except DeviceUnreachable as error:
                return StopResult(False, f"NMT stop not sent: {error}")
        sent_at = time.monotonic()
        try:
            for node_id in self.settings.drive_ids:
                self._send_nmt(NmtCommand.STOP, node_id)
                self._view.commanded(NmtCommand.STOP, node_id, sent_at)
        except (can.CanError, OSError) as error:
            self._bus_problem = f"sending on {self.settings.describe_bus()} failed: {error}"
            return StopResult(False, f"NMT stop not sent: {self._bus_problem}")
        sent_ms = (time.monotonic() - sent_at) * 1e3
        missing = self._await_stopped(sent_at)
        ids = ", ".join(map(str, self.settings.drive_ids))
        if missing:
            return StopResult(False, f"NMT stop sent to drives {ids} in {sent_ms:.1f} ms; no "
                              f"STOPPED heartbeat from {', '.join(map(str, missing))} within "
                              f"{self.confirm_s * 1e3:.0f} ms")
        confirmed_ms = (time.monotonic() - sent_at) * 1e3
        return StopResult(True, f"NMT stop sent to drives {ids} in {sent_ms:.1f} ms; every "
                          f"drive reported STOPPED within {confirmed_ms:.0f} ms")

    def probe(self) -> str | None:
        """The stop path is the bus itself (NMT has no answer): a bus that failed, or None."""
        if self._bus is None:
            return self._bus_problem or "the CAN bus is not open"
        return self._bus_problem

    def reconnect(self) -> bool:
        """Reopen a bus that failed; True once the drives are not lost any more."""
        if self._bus is None or self._bus_problem is not None:
            self.close()
            try:
                self.connect()
            except DeviceUnreachable as error:
                self._bus_problem = str(error)
                return False
        try:
            self._drain()
        except DeviceLost:
            return False
        return self._lost(time.monotonic()) is None

    def close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()

    # -- the bus -------------------------------------------------------------------------------

    def _lost(self, now: float) -> str | None:
        return self._view.lost(now, self.device_timeout_s, self.heartbeat_timeout_s,
                               self.settings.node_label)

    def _drain(self, timeout_s: float = 0.0) -> None:
        """Take every frame waiting; with a timeout, wait that long for the first one.

        Raises:
            DeviceLost: the bus is closed or reading it fails.
        """
        bus = self._bus
        if bus is None:
            raise DeviceLost(self._bus_problem or "the CAN bus is not open")
        wait = timeout_s
        for _ in range(DRAIN_LIMIT):
            try:
                message = bus.recv(wait)
            except (can.CanError, OSError) as error:
                self._bus_problem = f"reading {self.settings.describe_bus()} failed: {error}"
                raise DeviceLost(self._bus_problem) from error
            if message is None:
                self._read_empty_at = time.monotonic()
                return
            wait = 0.0
            if not (message.is_error_frame or message.is_remote_frame or message.is_extended_id):
                notice = self._view.take(message.arbitration_id, bytes(message.data),
                                         self._arrival(message.timestamp))
                if notice is not None:
                    _log(notice, self.settings.node_label(notice.node_id))

    def _arrival(self, stamp: float) -> float:
        """When a frame arrived, on the monotonic clock: its receive stamp (wall clock, taken
        by the kernel on SocketCAN and udp_multicast), kept between the last read that found
        nothing waiting and now, so a wall-clock step cannot date a frame outside the time it
        can have arrived in. A frame dated when it was read instead would look fresh after a
        stall of the reader, however old it is."""
        now = time.monotonic()
        return min(now, max(self._read_empty_at, now - (time.time() - stamp)))

    def _send_nmt(self, command: NmtCommand, node_id: int) -> None:
        bus = self._bus
        if bus is None:
            raise can.CanOperationError("the CAN bus is not open")
        bus.send(can.Message(arbitration_id=NMT_COB_ID, data=[command, node_id],
                             is_extended_id=False), timeout=SEND_TIMEOUT_S)

    def _await_stopped(self, sent_at: float) -> list[int]:
        """Drives whose heartbeat has not said STOPPED since ``sent_at`` by the deadline."""
        deadline = sent_at + self.confirm_s
        while missing := self._view.not_stopped_since(sent_at):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return missing
            try:
                self._drain(timeout_s=remaining)
            except DeviceLost:
                return missing
        return []


def _log(notice: Notice, who: str) -> None:
    if notice.kind is NoticeKind.EMERGENCY:
        log.warning("drive emergency", drive=who, detail=notice.detail)
    else:
        log.info("drive state", drive=who, detail=notice.detail)
