"""The policy link's timers, decided on times passed in (no clock, no task): the heartbeat and
the peer's silence, and the clock exchange (docs/protocol.md, "Heartbeats" and "Clock
synchronisation"). The protocol object (:mod:`kernel.shell.link_protocol`) asks each when it
next needs to be woken and what is due at an instant.
"""

from __future__ import annotations

from kernel import wire
from kernel.wire import ClockSample, ProtocolViolation


class Liveness:
    """Heartbeats every ``interval_ns`` from the connection's start; the peer is silent once
    nothing at all has come from it for ``timeout_ns`` (at exactly that bound)."""

    def __init__(self, interval_ns: int, timeout_ns: int) -> None:
        self.interval_ns, self.timeout_ns = interval_ns, timeout_ns
        self.last_rx = 0
        self._next_send = 0
        self._seq = 0

    def begin(self, now_ns: int) -> None:
        self.last_rx, self._next_send, self._seq = now_ns, now_ns + self.interval_ns, 0

    def heard(self, now_ns: int) -> None:
        """Anything from the peer (a dropped frame too) shows it is alive."""
        self.last_rx = max(self.last_rx, now_ns)

    def deadline(self) -> int:
        return min(self._next_send, self.last_rx + self.timeout_ns)

    def silent_for(self, now_ns: int) -> int | None:
        """How long the peer has been silent, once that reaches the bound (else None)."""
        silent = now_ns - self.last_rx
        return silent if silent >= self.timeout_ns else None

    def due(self, now_ns: int) -> list[tuple[int, bool]]:
        """The heartbeats due by ``now_ns`` (a stalled caller catches up): each one's sequence
        number and whether the peer was late by then (nothing for 1.5 intervals)."""
        due: list[tuple[int, bool]] = []
        while self._next_send <= now_ns:
            self._seq += 1
            due.append((self._seq, 2 * (now_ns - self.last_rx) > 3 * self.interval_ns))
            self._next_send += self.interval_ns
        return due


class ClockExchange:
    """One burst of pings, one at a time; the sample with the smallest round trip is the sync.

    ``burst`` 0: no exchange (the peer reads the robot's clock). :attr:`sample` is the sync in
    force and outlives the connection it was taken on.
    """

    def __init__(self, burst: int, ping_timeout_ns: int, refresh_ns: int) -> None:
        self.burst, self.ping_timeout_ns, self.refresh_ns = burst, ping_timeout_ns, refresh_ns
        self.sample: ClockSample | None = None
        self._samples: list[ClockSample] = []
        self._seq = 0
        self._in_flight: wire.ClockPing | None = None
        self._refresh_at: int | None = None

    def begin(self) -> None:
        self._samples, self._seq, self._in_flight, self._refresh_at = [], 0, None, None

    def ping(self, now_ns: int) -> wire.ClockPing:
        """The next ping (a burst starts with an empty sample list)."""
        self._seq += 1
        self._in_flight = wire.ClockPing(seq=self._seq, t0=now_ns)
        self._refresh_at = None
        return self._in_flight

    def start(self, now_ns: int) -> wire.ClockPing:
        self._samples = []
        return self.ping(now_ns)

    def pong(self, pong: wire.ClockPong, now_ns: int) -> wire.ClockPing | ClockSample | None:
        """Take a pong read at ``now_ns``: the burst's next ping to send, or its best sample
        once the burst is complete (the sync in force from now on). None: a pong for no ping
        in flight (one that timed out), dropped.

        Raises:
            ProtocolViolation: the pong does not echo its ping, or implies an implausible
                offset (it never reaches the core).
        """
        ping = self._in_flight
        if ping is None or pong.seq != ping.seq:
            return None
        sample = wire.clock_sample(ping.t0, pong, now_ns)
        self._in_flight = None
        self._samples.append(sample)
        if len(self._samples) < self.burst:
            return self.ping(now_ns)
        best = wire.best_sample(self._samples)
        if best is None:
            raise ProtocolViolation("no usable clock sample")
        self.sample = best
        return best

    def schedule_refresh(self, now_ns: int) -> None:
        self._refresh_at = now_ns + self.refresh_ns

    def deadline(self) -> int | None:
        """The ping's timeout while one is in flight, else the next refresh (None: none)."""
        if self._in_flight is not None:
            return self._in_flight.t0 + self.ping_timeout_ns
        return self._refresh_at

    def ping_timed_out(self, now_ns: int) -> bool:
        ping = self._in_flight
        return ping is not None and now_ns >= ping.t0 + self.ping_timeout_ns

    def refresh_due(self, now_ns: int) -> bool:
        return self._refresh_at is not None and now_ns >= self._refresh_at
