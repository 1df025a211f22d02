"""What one policy peer may make the robot side do, decided on times passed in (no clock).

The policy link shares the event loop (and the GIL) with the control loop, so whatever a peer
sends is paid for in the control period. The protocol object (:mod:`kernel.shell.link_protocol`)
keeps it bounded with these, whatever the peer does:

- :class:`TokenBucket`: at most so many frames, and so many chunks, per second (with a burst of
  a tenth of a second's worth). What exceeds the rate is dropped and counted before it is
  decoded.
- :class:`RequestWindow`: at most so many observations in flight (sent and not yet answered);
  an observation unanswered for the request timeout stops counting.
- :class:`ChunkQueue`: the chunks waiting for an admission slot. The first chunk citing an
  observation in flight is the expected answer: it bypasses the chunk rate and goes first (there
  are at most as many as requests in flight), so a flood does not crowd out the answer the robot
  waits for; at most :data:`OTHERS_QUEUED` others wait.

Each holds plain numbers; every time is the caller's ``now_ns``. Nothing here decides about a
chunk: the core does, for every chunk that gets through.
"""

from __future__ import annotations

import math
from collections import OrderedDict, deque

import msgspec

from kernel.shell.link_types import LinkCounters
from kernel.wire import Frame

BURST_S = 0.1
"""A bucket holds this long's worth of its rate: a legitimate burst (a duplicate and its
original, a reordered pair) passes, a flood does not."""
OTHERS_QUEUED = 4
"""Chunks that answer nothing in flight, waiting for admission: enough for a legitimate burst
(a chunk and its duplicate, a reordered pair), short enough that a flood adds no latency."""


class TokenBucket:
    """``rate_per_s`` tokens a second, at most ``burst`` of them saved up (full at first)."""

    def __init__(self, rate_per_s: float) -> None:
        if not rate_per_s > 0:
            raise ValueError(f"a rate limit must be positive, got {rate_per_s!r}")
        self.rate = rate_per_s
        self.burst = max(1.0, math.ceil(rate_per_s * BURST_S))
        self._tokens = self.burst
        self._at: int | None = None

    def take(self, now_ns: int) -> bool:
        """Spend one token at ``now_ns``; False (nothing spent) when the rate is exhausted."""
        if self._at is not None:
            refill = max(0, now_ns - self._at) * self.rate / 1e9
            self._tokens = min(self.burst, self._tokens + refill)
        self._at = now_ns
        if self._tokens < 1.0:
            return False
        self._tokens -= 1.0
        return True


class RequestWindow:
    """Observations in flight: sent to the server and not answered yet (bounded)."""

    def __init__(self, limit: int, timeout_ns: int) -> None:
        if limit < 1 or not timeout_ns > 0:
            raise ValueError("need at least one request in flight and a positive timeout")
        self.limit, self.timeout_ns = limit, timeout_ns
        self.expired = 0
        self._sent: OrderedDict[str, int] = OrderedDict()
        self._claimed: set[str] = set()

    def __len__(self) -> int:
        return len(self._sent)

    def open(self, now_ns: int) -> bool:
        """True when one more observation may go out (expired ones are dropped first)."""
        while self._sent and next(iter(self._sent.values())) + self.timeout_ns <= now_ns:
            oldest, _ = self._sent.popitem(last=False)
            self._claimed.discard(oldest)
            self.expired += 1
        return len(self._sent) < self.limit

    def deadline(self) -> int | None:
        """When the oldest request in flight expires (None: none in flight)."""
        if not self._sent:
            return None
        return next(iter(self._sent.values())) + self.timeout_ns

    def sent(self, observation_id: str, now_ns: int) -> None:
        self._sent[observation_id] = now_ns

    def claim(self, observation_id: str) -> bool:
        """True for the first chunk citing an observation in flight: it is the expected
        answer and bypasses the chunk rate (later ones citing it do not)."""
        if observation_id not in self._sent or observation_id in self._claimed:
            return False
        self._claimed.add(observation_id)
        return True

    def answered(self, observation_id: str | None) -> int | None:
        """A chunk citing ``observation_id`` was fed (admitted or not): when that observation
        was sent (None: it was not in flight). One whose observation cannot be read (a
        malformed chunk: None) answers the oldest request: servers answer in order, and a
        request must not stay blocked by an answer that was unreadable."""
        if observation_id is None:
            if not self._sent:
                return None
            observation_id, sent = self._sent.popitem(last=False)
        else:
            sent = self._sent.pop(observation_id, None)
            if sent is None:
                return None
        self._claimed.discard(observation_id)
        return sent

    def clear(self) -> None:
        """A new session: nothing of the old one is in flight."""
        self._sent.clear()
        self._claimed.clear()


class _Cites(msgspec.Struct, frozen=True):
    """The one field of a chunk body read before admission."""

    observation_id: str = ""


_cites = msgspec.msgpack.Decoder(_Cites)


def cited_observation(body: bytes) -> str | None:
    """The observation a chunk body cites, or None when it cannot be read (the core will say
    why: MALFORMED)."""
    try:
        return _cites.decode(body).observation_id
    except (msgspec.DecodeError, ValueError, RecursionError):
        return None


class ChunkQueue:
    """Chunk frames of the session waiting for an admission slot (see the module docstring)."""

    def __init__(self, rate_per_s: float, window: RequestWindow,
                 counters: LinkCounters) -> None:
        self._bucket = TokenBucket(rate_per_s)
        self._window, self._counters = window, counters
        self._expected: deque[Frame] = deque()
        """First chunks citing a request in flight: at most one per request."""
        self._others: deque[Frame] = deque()

    def __len__(self) -> int:
        return len(self._expected) + len(self._others)

    def put(self, frame: Frame, now_ns: int) -> bool:
        """Queue a chunk frame, or drop it (counted): False when dropped."""
        self._counters.chunks_in += 1
        cited = cited_observation(frame.body)
        if cited is not None and self._window.claim(cited):
            self._expected.append(frame)
        elif self._bucket.take(now_ns) and len(self._others) < OTHERS_QUEUED:
            self._others.append(frame)
        else:
            self._counters.chunks_dropped += 1  # over the rate, or enough already waiting
            return False
        return True

    def pop(self) -> Frame | None:
        """The next chunk to admit: expected answers first."""
        queue = self._expected or self._others
        return queue.popleft() if queue else None

    def clear(self) -> None:
        self._expected.clear()
        self._others.clear()
