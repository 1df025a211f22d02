"""Bounded work per policy peer: what one server can make the robot side do, and when.

The policy link shares the event loop (and the GIL) with the control loop, so whatever a peer
sends is paid for in the control period. Three limits keep that bounded, whatever the peer does:

- :class:`TokenBucket`: at most so many frames, and so many chunks, per second (with a burst of
  a tenth of a second's worth). What exceeds the rate is dropped and counted before it is
  decoded. The first chunk citing an observation in flight is the expected answer: it bypasses
  the chunk rate (there are at most as many as requests in flight), so a flood does not crowd
  out the answer the robot waits for.
- :class:`RequestWindow`: at most so many observations in flight (sent and not yet answered);
  an observation unanswered for the request timeout stops counting.
- :class:`AdmissionPacer`: at most so many chunk admissions per control period, started either
  right after the period's tick or while at least half of the period remains, so that an
  admission (about half a millisecond, docs/architecture.md) ends before the next deadline.

Each holds plain numbers and a monotonic clock; nothing here decides about a chunk: the core
does, for every chunk that gets through.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import OrderedDict
from collections.abc import Callable

BURST_S = 0.1
"""A bucket holds this long's worth of its rate: a legitimate burst (a duplicate and its
original, a reordered pair) passes, a flood does not."""


class TokenBucket:
    """``rate_per_s`` tokens a second, at most ``burst`` of them saved up."""

    def __init__(self, rate_per_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        if not rate_per_s > 0:
            raise ValueError(f"a rate limit must be positive, got {rate_per_s!r}")
        self.rate = rate_per_s
        self.burst = max(1.0, math.ceil(rate_per_s * BURST_S))
        self._clock = clock
        self._tokens = self.burst
        self._at = clock()

    def take(self) -> bool:
        """Spend one token; False (nothing spent) when the rate is exhausted."""
        now = self._clock()
        self._tokens = min(self.burst, self._tokens + (now - self._at) * self.rate)
        self._at = now
        if self._tokens < 1.0:
            return False
        self._tokens -= 1.0
        return True


class RequestWindow:
    """Observations in flight: sent to the server and not answered yet (bounded)."""

    def __init__(self, limit: int, timeout_s: float,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if limit < 1 or not timeout_s > 0:
            raise ValueError("need at least one request in flight and a positive timeout")
        self.limit, self.timeout_s = limit, timeout_s
        self.expired = 0
        self._clock = clock
        self._sent: OrderedDict[str, float] = OrderedDict()
        self._claimed: set[str] = set()
        self.changed = asyncio.Event()
        """Set when a slot may have come free (an answer); the sender clears it."""

    def __len__(self) -> int:
        return len(self._sent)

    def open(self) -> bool:
        """True when one more observation may go out (expired ones are dropped first)."""
        cutoff = self._clock() - self.timeout_s
        while self._sent and next(iter(self._sent.values())) <= cutoff:
            oldest, _ = self._sent.popitem(last=False)
            self._claimed.discard(oldest)
            self.expired += 1
        return len(self._sent) < self.limit

    def wait_s(self) -> float:
        """How long until the oldest request in flight expires."""
        if not self._sent:
            return 0.0
        return max(0.0, next(iter(self._sent.values())) + self.timeout_s - self._clock())

    def sent(self, observation_id: str) -> None:
        self._sent[observation_id] = self._clock()

    def claim(self, observation_id: str) -> bool:
        """True for the first chunk citing an observation in flight: it is the expected
        answer and bypasses the chunk rate (later ones citing it do not)."""
        if observation_id not in self._sent or observation_id in self._claimed:
            return False
        self._claimed.add(observation_id)
        return True

    def answered(self, observation_id: str | None) -> None:
        """A chunk citing ``observation_id`` arrived (admitted or not). One whose observation
        cannot be read (a malformed chunk: None) answers the oldest request: servers answer
        in order, and a request must not stay blocked by an answer that was unreadable."""
        if observation_id is None and self._sent:
            observation_id, _ = self._sent.popitem(last=False)
        elif self._sent.pop(observation_id, None) is None:  # type: ignore[arg-type]
            return
        self._claimed.discard(observation_id)  # type: ignore[arg-type]
        self.changed.set()

    def clear(self) -> None:
        """A new session: nothing of the old one is in flight."""
        self._sent.clear()
        self._claimed.clear()
        self.changed.set()


class AdmissionPacer:
    """Places chunk admissions in the control period where they cannot cost a deadline.

    The control loop calls :meth:`period_done` after each tick with the next deadline; the
    link awaits :meth:`slot` before each admission. A slot is granted at once while fewer than
    ``per_period`` admissions ran in this period and at least ``reserve_ns`` remain before the
    next deadline; otherwise the admission waits for the end of the next tick, where the waiting
    ones run first (so a period whose tick ran long still admits ``per_period`` chunks).
    """

    def __init__(self, per_period: int, reserve_ns: int,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        if per_period < 1 or reserve_ns < 0:
            raise ValueError("need at least one admission per period and a reserve >= 0")
        self.per_period, self.reserve_ns = per_period, reserve_ns
        self.deferred = 0
        """Admissions that waited for a later period."""
        self._clock = clock
        self._used = 0
        self._window_end_ns = -1
        self._next: asyncio.Future[None] | None = None

    def period_done(self, next_deadline_ns: int) -> None:
        """The tick of this period is written: admissions may run until the reserve."""
        self._used = 0
        self._window_end_ns = next_deadline_ns - self.reserve_ns
        waiters, self._next = self._next, None
        if waiters is not None and not waiters.done():
            waiters.set_result(None)

    async def slot(self) -> None:
        """Return when an admission may run now (see the class docstring)."""
        if self._used < self.per_period and self._clock() < self._window_end_ns:
            self._used += 1
            return
        self.deferred += 1
        while True:
            if self._next is None:
                self._next = asyncio.get_running_loop().create_future()
            await asyncio.shield(self._next)
            if self._used < self.per_period:
                self._used += 1
                return
