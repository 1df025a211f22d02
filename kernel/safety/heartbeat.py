"""The monitor's side of warden's heartbeat (the sender and the wire format:
kernel/shell/heartbeat.py).

The monitor binds the Unix datagram socket (0660, to the configured group) with SO_PASSCRED, so
the kernel attaches the sender's pid, uid and gid to every datagram. A datagram whose payload
names another pid than the kernel's is refused (counted, logged once). A heartbeat's time is the
sender's CLOCK_MONOTONIC stamp, never its arrival: a datagram that waited in the queue while
warden was already stopped does not count as fresh.

States (:class:`Pulse`): NONE, no warden run is heartbeating (none since the monitor started, or
the last one sent END); ALIVE, the newest heartbeat is younger than ``heartbeat_timeout_ms``;
CLOSING, the run's loop has ended in order and it is holding the arm and closing the device
(for up to ``closing_timeout_ms``); LOST, either of those timeouts has passed. One run (one
session id) is followed at a time; another run's heartbeats are taken up only once the current
one has ended or been lost.
"""

from __future__ import annotations

import contextlib
import os
import socket
import struct
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import structlog

from kernel.shell.heartbeat import WIRE, Beat, BeatKind

log = structlog.get_logger("warden.safety")
_CREDENTIALS = struct.Struct("3i")  # struct ucred: pid, uid, gid
_FUTURE_TOLERANCE_NS = 1_000_000
"""A stamp this far ahead of the monitor's own clock (the same clock) is not a real one."""


class Pulse(StrEnum):
    NONE = "none"
    ALIVE = "alive"
    CLOSING = "closing"
    LOST = "lost"


@dataclass(slots=True)
class Session:
    session: int
    pid: int
    uid: int
    last_seq: int
    last_ns: int
    closing_ns: int | None = None
    """When warden said CLOSING (its stamp), or None."""


@dataclass(slots=True)
class PulseCounters:
    received: int = 0
    refused: int = 0
    sessions: int = 0


class HeartbeatReceiver:
    def __init__(self, path: Path, gid: int, timeout_ns: int, closing_timeout_ns: int) -> None:
        self.path, self.timeout_ns, self.closing_timeout_ns = path, timeout_ns, closing_timeout_ns
        self.counters = PulseCounters()
        self.current: Session | None = None
        self._refusals_logged: set[str] = set()
        _unlink_stale(path)
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)
            self._sock.bind(str(path))
            os.chown(path, -1, gid)
            os.chmod(path, 0o660)
        except OSError:
            self._sock.close()
            raise
        self._sock.setblocking(False)

    def fileno(self) -> int:
        return self._sock.fileno()

    def state(self, now_ns: int) -> Pulse:
        current = self.current
        if current is None:
            return Pulse.NONE
        if current.closing_ns is not None:
            late = now_ns - current.closing_ns > self.closing_timeout_ns
            return Pulse.LOST if late else Pulse.CLOSING
        return Pulse.LOST if now_ns - current.last_ns > self.timeout_ns else Pulse.ALIVE

    def age_ms(self, now_ns: int) -> float | None:
        return None if self.current is None else (now_ns - self.current.last_ns) / 1e6

    def drain(self, now_ns: int) -> None:
        """Take every datagram waiting (never blocks)."""
        while True:
            try:
                data, ancillary, _, _ = self._sock.recvmsg(WIRE.size + 1,
                                                           socket.CMSG_SPACE(_CREDENTIALS.size))
            except (BlockingIOError, InterruptedError):
                return
            self._take(data, _credentials(ancillary), now_ns)

    def close(self) -> None:
        self._sock.close()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

    def _take(self, data: bytes, sender: tuple[int, int, int] | None, now_ns: int) -> None:
        try:
            beat = Beat.unpack(data)
        except ValueError as error:
            self._refuse("malformed", str(error))
            return
        if sender is None or sender[0] != beat.pid:
            self._refuse("forged", f"payload pid {beat.pid}, sent by pid "
                                   f"{sender[0] if sender else '?'}")
            return
        if beat.t_mono_ns > now_ns + _FUTURE_TOLERANCE_NS:
            self._refuse("future", f"stamp {(beat.t_mono_ns - now_ns) / 1e6:.1f} ms ahead")
            return
        self.counters.received += 1
        self._follow(beat, sender[1], now_ns)

    def _follow(self, beat: Beat, uid: int, now_ns: int) -> None:
        current = self.current
        if current is None or current.session != beat.session:
            if current is not None and self.state(now_ns) is not Pulse.LOST:
                self._refuse("second run", f"pid {beat.pid} heartbeats while pid "
                                           f"{current.pid} still does")
                return
            if beat.kind is not BeatKind.BEAT:
                return  # the end of a run this monitor never followed
            self.current = Session(beat.session, beat.pid, uid, beat.seq, beat.t_mono_ns)
            self.counters.sessions += 1
            log.info("warden heartbeat", pid=beat.pid, uid=uid, session=f"{beat.session:016x}")
            return
        if beat.seq <= current.last_seq:
            return  # a duplicate or a reordered datagram: nothing new
        lost = self.state(now_ns) is Pulse.LOST
        current.last_seq, current.last_ns = beat.seq, max(current.last_ns, beat.t_mono_ns)
        if beat.kind is BeatKind.END:
            log.info("warden ended its run", pid=beat.pid)
            self.current = None
        elif beat.kind is BeatKind.CLOSING:
            current.closing_ns = beat.t_mono_ns
            log.info("warden is closing its run", pid=beat.pid)
        elif lost:
            log.warning("warden heartbeat back after it was lost", pid=beat.pid)

    def _refuse(self, kind: str, detail: str) -> None:
        self.counters.refused += 1
        if kind not in self._refusals_logged:
            self._refusals_logged.add(kind)
            log.warning("heartbeat refused", kind=kind, detail=detail)


def _credentials(ancillary: list[tuple[int, int, bytes]]) -> tuple[int, int, int] | None:
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == socket.SCM_CREDENTIALS and len(data) >= 12:
            pid, uid, gid = _CREDENTIALS.unpack(data[:_CREDENTIALS.size])
            return pid, uid, gid
    return None


def _unlink_stale(path: Path) -> None:
    """A socket left by a monitor that died may go; one somebody still receives on may not.

    Raises:
        OSError: another monitor is bound to ``path``.
    """
    if not path.is_socket():
        return
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        probe.connect(str(path))
    except OSError:
        path.unlink()
    else:
        raise OSError(f"{path}: another safety monitor receives on this socket")
    finally:
        probe.close()
