"""A dependency-free sd_notify client: readiness, status, watchdog pings and stopping.

systemd passes ``NOTIFY_SOCKET`` to a ``Type=notify`` service: the address of an AF_UNIX
datagram socket (a filesystem path, or an abstract-namespace name when it starts with ``@``).
Each datagram is newline-separated ``KEY=VALUE`` fields (``READY=1``, ``STATUS=...``,
``WATCHDOG=1``, ``STOPPING=1``). With ``WatchdogSec=`` set, systemd also passes
``WATCHDOG_USEC`` (and ``WATCHDOG_PID``) and kills the service when ``WATCHDOG=1`` stops
arriving for that long after ``READY=1``.

Everything here is a no-op when ``NOTIFY_SOCKET`` is unset (a terminal, a test, CI). Sends are
non-blocking and never raise into the caller: a full or vanished notify socket must not stall
or crash the control loop, so :class:`ServiceNotifier` counts failures instead (the watchdog
itself then reports a real problem by restarting the service).
"""

from __future__ import annotations

import errno
import os
import re
import socket
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

NOTIFY_SOCKET = "NOTIFY_SOCKET"
WATCHDOG_USEC = "WATCHDOG_USEC"
WATCHDOG_PID = "WATCHDOG_PID"
STATUS_MAX_CHARS = 200
"""systemctl shows one STATUS line; longer text is cut so a datagram stays small."""

_KEY = re.compile(r"[A-Z][A-Z0-9_]*\Z")
Address = str | bytes


def notify_address(env: Mapping[str, str] | None = None) -> Address | None:
    """The socket address in ``NOTIFY_SOCKET``, or None when unset or not an AF_UNIX address.

    ``@name`` is Linux's abstract namespace (a leading NUL byte on the wire). systemd also
    knows ``vsock:`` addresses (for VMs); a robot PC has no use for them, so they count as unset.
    """
    value = (os.environ if env is None else env).get(NOTIFY_SOCKET, "")
    if value.startswith("@") and len(value) > 1:
        return b"\0" + value[1:].encode()
    if value.startswith("/"):
        return value
    return None


def watchdog_interval_s(env: Mapping[str, str] | None = None, pid: int | None = None
                        ) -> float | None:
    """The watchdog timeout in seconds, or None when this process is not under a watchdog.

    As ``sd_watchdog_enabled``: ``WATCHDOG_USEC`` must be a positive integer, and when
    ``WATCHDOG_PID`` is set it must be this process (a child that inherited the variables is
    not the one systemd watches).
    """
    env = os.environ if env is None else env
    raw_usec, raw_pid = env.get(WATCHDOG_USEC, ""), env.get(WATCHDOG_PID, "")
    if not raw_usec.isdigit() or int(raw_usec) == 0:
        return None
    if raw_pid and (not raw_pid.isdigit() or int(raw_pid) != (os.getpid() if pid is None
                                                               else pid)):
        return None
    return int(raw_usec) / 1e6


def message(**fields: object) -> bytes:
    """The datagram for ``fields``: ``KEY=VALUE`` lines, in the order given.

    ``True`` is written as ``1``. A newline inside a value would start a new (forged) field,
    so it is replaced by a space. A key that is not upper-case ASCII is a programming error.
    """
    lines = []
    for key, value in fields.items():
        if not _KEY.match(key):
            raise ValueError(f"sd_notify field {key!r}: expected an upper-case name like READY")
        text = "1" if value is True else str(value)
        lines.append(f"{key}={text.replace(chr(10), ' ')}")
    return "\n".join(lines).encode()


def notify(env: Mapping[str, str] | None = None, **fields: object) -> bool:
    """Send one notification (``notify(READY=1, STATUS="up")``); True if it was sent.

    Opens a socket for this one message: for occasional calls. A service that pings the
    watchdog keeps a :class:`ServiceNotifier` instead.
    """
    address = notify_address(env)
    if address is None:
        return False
    payload = message(**fields)
    channel = _Channel(address)
    try:
        return channel.send(payload) is None
    finally:
        channel.close()


@dataclass(slots=True)
class NotifierStats:
    sent: int = 0
    failed: int = 0
    last_error: str | None = None
    """The errno name of the last failure (``EAGAIN``, ``ECONNREFUSED``...): a bounded label."""


class ServiceNotifier:
    """What the shell tells systemd: ``ready``, ``status``, ``alive`` and ``stopping``.

    ``alive()`` is meant to be called from the control loop after every healthy tick; it sends
    ``WATCHDOG=1`` at most once per half watchdog interval (systemd's recommendation), so a
    500 Hz loop costs one datagram a second. A stuck loop stops calling it, the pings stop, and
    systemd restarts the service. Without ``NOTIFY_SOCKET`` every method does nothing.
    """

    def __init__(self, address: Address | None, watchdog_s: float | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.enabled = address is not None
        self.watchdog_s = watchdog_s if self.enabled else None
        self.stats = NotifierStats()
        self._ping_every = None if self.watchdog_s is None else self.watchdog_s / 2
        self._clock = clock
        self._last_ping: float | None = None
        self._channel = _Channel(address) if address is not None else None

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> ServiceNotifier:
        """Configured from ``NOTIFY_SOCKET``, ``WATCHDOG_USEC`` and ``WATCHDOG_PID``."""
        return cls(notify_address(env), watchdog_interval_s(env), clock)

    def ready(self, status: str) -> bool:
        """Start-up is complete (systemd arms the watchdog from here). With a watchdog, the
        datagram restates its timeout (``WATCHDOG_USEC``): a held start lengthens it for the
        bring-up after an operator's confirmation (:meth:`extend_watchdog`), and the loop's
        readiness puts the unit's own back."""
        if self.watchdog_s is None:
            return self._send(READY=1, STATUS=_short(status))
        return self._send(READY=1, STATUS=_short(status),
                          WATCHDOG_USEC=round(self.watchdog_s * 1e6))

    def extend_watchdog(self, seconds: float) -> bool:
        """Let ``seconds`` pass without a ping (a bring-up with no loop yet to ping); the next
        :meth:`ready` restores the unit's timeout. Nothing is sent without a watchdog."""
        if self.watchdog_s is None:
            return False
        return self._send(WATCHDOG_USEC=round(seconds * 1e6))

    def status(self, text: str) -> bool:
        return self._send(STATUS=_short(text))

    def alive(self) -> bool:
        """A watchdog ping, rate-limited; True only when a datagram was sent."""
        if self._ping_every is None:
            return False
        now = self._clock()
        if self._last_ping is not None and now - self._last_ping < self._ping_every:
            return False
        # Counted as a ping even if the send fails: retrying every tick would not help a full
        # socket, and would cost a syscall per tick.
        self._last_ping = now
        return self._send(WATCHDOG=1)

    def stopping(self, status: str | None = None) -> bool:
        fields: dict[str, object] = {"STOPPING": 1}
        if status is not None:
            fields["STATUS"] = _short(status)
        return self._send(**fields)

    def close(self) -> None:
        if self._channel is not None:
            self._channel.close()

    def __enter__(self) -> ServiceNotifier:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _send(self, **fields: object) -> bool:
        if self._channel is None:
            return False
        error = self._channel.send(message(**fields))
        if error is None:
            self.stats.sent += 1
            return True
        self.stats.failed += 1
        self.stats.last_error = error
        return False


class _Channel:
    """One non-blocking datagram socket; ``send`` returns None or the errno name."""

    def __init__(self, address: Address) -> None:
        self._address = address
        self._socket: socket.socket | None = None

    def send(self, payload: bytes) -> str | None:
        try:
            if self._socket is None:
                self._socket = socket.socket(socket.AF_UNIX,
                                             socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                self._socket.setblocking(False)
            self._socket.sendto(payload, self._address)
        except OSError as error:
            return errno.errorcode.get(error.errno or 0, type(error).__name__)
        return None

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None


def _short(text: str) -> str:
    return text if len(text) <= STATUS_MAX_CHARS else text[:STATUS_MAX_CHARS - 1] + "…"


__all__ = ["NotifierStats", "ServiceNotifier", "message", "notify", "notify_address",
           "watchdog_interval_s"]
