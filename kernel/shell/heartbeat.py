"""warden's heartbeat to the independent safety monitor (``warden safety``, kernel/safety).

The control loop calls :meth:`HeartbeatSender.beat` after every completed tick; every
``heartbeat_periods``-th call sends one datagram to the monitor's Unix datagram socket
(``[safety] heartbeat_socket``). A loop that stops completing ticks (a hang, SIGSTOP, a crash)
stops the heartbeat, and the monitor stops the arm once ``heartbeat_timeout_ms`` has passed.
When the loop ends in order, :meth:`closing` sends CLOSING (no more ticks: warden is holding
the arm and closing the device, which takes longer than a heartbeat's timeout with some vendor
libraries; the monitor then waits up to ``closing_timeout_ms``), and once the arm is held and
the device closed, :meth:`close` sends END, so the monitor knows the silence that follows is
not a failure.

Why a Unix datagram socket and not UDP on loopback: only members of the socket file's group
can send to it (any local process can send to a UDP port), the kernel attaches the sender's
pid, uid and gid to every datagram (SO_PASSCRED), which the monitor checks against the pid in
the payload, and a datagram is never half-delivered. Sends are non-blocking and never raise
into the loop: a monitor that is not there costs one failed ``sendto`` per heartbeat, counted
and logged once.

Wire format (little-endian, 40 bytes): magic ``WDHB``, kind (1 beat, 2 end, 3 closing), 3 pad
bytes,
pid (u32), session (u64, random per run), seq (u64, from 0), t_mono_ns (u64, CLOCK_MONOTONIC
of the sender at the send; the monitor judges the heartbeat's age by it, so a datagram that
sat in a queue is not mistaken for a fresh one).
"""

from __future__ import annotations

import errno
import os
import secrets
import socket
import struct
import time
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path

import structlog

log = structlog.get_logger("warden.heartbeat")
MAGIC = b"WDHB"
WIRE = struct.Struct("<4sB3xIQQQ")


class BeatKind(IntEnum):
    BEAT = 1
    END = 2
    CLOSING = 3


@dataclass(frozen=True, slots=True)
class Beat:
    kind: BeatKind
    pid: int
    session: int
    seq: int
    t_mono_ns: int

    def pack(self) -> bytes:
        return WIRE.pack(MAGIC, self.kind, self.pid, self.session, self.seq, self.t_mono_ns)

    @classmethod
    def unpack(cls, data: bytes) -> Beat:
        """Raises:
            ValueError: not a heartbeat of this format.
        """
        if len(data) != WIRE.size:
            raise ValueError(f"{len(data)} bytes, a heartbeat has {WIRE.size}")
        magic, kind, pid, session, seq, t_ns = WIRE.unpack(data)
        if magic != MAGIC:
            raise ValueError("not a warden heartbeat (magic)")
        return cls(BeatKind(kind), pid, session, seq, t_ns)


@dataclass(slots=True)
class HeartbeatStats:
    sent: int = 0
    failed: int = 0
    last_error: str | None = None
    """The errno name of the last failure (ENOENT: no monitor; EAGAIN: its queue is full)."""


class HeartbeatSender:
    """One run's heartbeat. Cheap when disabled (no ``[safety]`` table): every call returns."""

    def __init__(self, path: Path | None, every_ticks: int = 5) -> None:
        self.path = path
        self.every_ticks = max(1, every_ticks)
        self.stats = HeartbeatStats()
        self._session = secrets.randbits(64)
        self._pid = os.getpid()
        self._ticks = 0
        self._seq = 0
        self._closing = False
        self._socket: socket.socket | None = None
        if path is not None:
            self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._socket.setblocking(False)

    @property
    def enabled(self) -> bool:
        return self._socket is not None

    def beat(self) -> bool:
        """After a completed tick; True when this call sent a heartbeat."""
        if self._socket is None or self._closing:
            return False
        due = self._ticks % self.every_ticks == 0  # the first completed tick sends at once
        self._ticks += 1
        return self._send(BeatKind.BEAT) if due else False

    def closing(self) -> None:
        """The loop has ended in order: no more heartbeats, the device is being closed."""
        if self._socket is not None and not self._closing:
            self._closing = True
            self._send(BeatKind.CLOSING)

    def close(self) -> None:
        """The run ended in order (the arm held, the device closed): say so, then close."""
        if self._socket is None:
            return
        self._send(BeatKind.END)
        self._socket.close()
        self._socket = None

    def summary(self) -> dict[str, object]:
        return {"socket": str(self.path) if self.path else "-", "sent": self.stats.sent,
                "failed": self.stats.failed, "last_error": self.stats.last_error}

    def _send(self, kind: BeatKind) -> bool:
        beat = Beat(kind, self._pid, self._session, self._seq, time.monotonic_ns())
        self._seq += 1
        try:
            self._socket.sendto(beat.pack(), str(self.path))  # type: ignore[union-attr]
        except OSError as error:
            self._failed(errno.errorcode.get(error.errno or 0, type(error).__name__))
            return False
        if self.stats.failed and self.stats.last_error is not None:
            log.info("safety monitor heartbeat delivered again", socket=str(self.path))
            self.stats.last_error = None
        self.stats.sent += 1
        return True

    def _failed(self, name: str) -> None:
        self.stats.failed += 1
        if name != self.stats.last_error:  # one line per kind of failure, not one per beat
            log.warning("no safety monitor takes the heartbeat", socket=str(self.path),
                        error=name)
        self.stats.last_error = name


__all__ = ["WIRE", "Beat", "BeatKind", "HeartbeatSender", "HeartbeatStats"]
