"""The policy link's chunk intake: from a chunk frame to a chunk event, at a bounded cost.

A chunk frame is queued if it is the first to cite an observation in flight (the answer the robot
waits for: read from the frame with a decoder that skips everything else; it is admitted before
any other), or else if the chunk rate allows it and fewer than :data:`OTHERS_QUEUED` others are
waiting; any other is dropped and counted, never fed. An admission task then feeds the queued
chunks to the core one admission slot at a time (:class:`~kernel.shell.link_budget.
AdmissionPacer`), decoding each only then, stamped with the instant it is decided. A fed chunk
answers its request in the window of requests in flight; what the core decided on it reaches
the link as a typed :class:`~kernel.core.effects.ChunkDecision` (whichever event decided it:
the chunk's own, or its job's result).
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable

import msgspec

from assurance.envelope import Chunk
from kernel.core import events as ev
from kernel.shell.link_budget import AdmissionPacer, RequestWindow, TokenBucket
from kernel.shell.link_types import Gateway, LinkCounters
from kernel.wire import Frame

OTHERS_QUEUED = 4
"""Chunks that answer nothing in flight, waiting for admission: enough for a legitimate burst
(a chunk and its duplicate, a reordered pair), short enough that a flood adds no latency."""


class _Cites(msgspec.Struct, frozen=True):
    """The one field of a chunk body the intake reads before admission."""

    observation_id: str = ""


_cites = msgspec.msgpack.Decoder(_Cites)


def cited_observation(body: bytes) -> str | None:
    """The observation a chunk body cites, or None when it cannot be read (the core will say
    why: MALFORMED)."""
    try:
        return _cites.decode(body).observation_id
    except (msgspec.DecodeError, ValueError, RecursionError):
        return None


class ChunkIntake:
    def __init__(self, gateway: Gateway, counters: LinkCounters, rate_per_s: float,
                 window: RequestWindow, pacer: AdmissionPacer | None,
                 chunk_event: Callable[[Frame, int], ev.ChunkEvent]) -> None:
        self._gateway, self._counters, self._window = gateway, counters, window
        self._pacer, self._chunk_event = pacer, chunk_event
        self._bucket = TokenBucket(rate_per_s)
        self._expected: deque[Frame] = deque()
        """First chunks citing a request in flight: at most one per request."""
        self._others: deque[Frame] = deque()
        self._arrived = asyncio.Event()
        self._open = False

    def begin(self) -> None:
        """A new connection: its chunks may be fed."""
        self._clear()
        self._open = True

    def end(self) -> None:
        """The core has been told the link is down: nothing queued on it is ever fed."""
        self._open = False
        self._clear()

    def _clear(self) -> None:
        self._expected.clear()
        self._others.clear()

    def put(self, frame: Frame) -> None:
        """Queue a chunk frame of an accepted session, or drop it (counted)."""
        self._counters.chunks_in += 1
        cited = cited_observation(frame.body)
        if cited is not None and self._window.claim(cited):
            self._expected.append(frame)
        elif self._bucket.take() and len(self._others) < OTHERS_QUEUED:
            self._others.append(frame)
        else:
            self._counters.chunks_dropped += 1  # over the rate, or enough already waiting
            return
        self._arrived.set()

    async def run(self) -> None:
        """Feed queued chunks to the core, one admission slot at a time (until cancelled)."""
        while True:
            while not (self._expected or self._others):
                self._arrived.clear()
                await self._arrived.wait()
            if self._pacer is None:
                await asyncio.sleep(0)  # still never two admissions without yielding
            else:
                await self._pacer.slot()
                self._counters.admissions_deferred = self._pacer.deferred
            queue = self._expected or self._others
            if self._open and queue:
                self._feed(queue.popleft())

    def _feed(self, frame: Frame) -> None:
        # Decided now, decoded now (the protocol's decoder): the core's clock only moves forward.
        event = self._chunk_event(frame, self._gateway.now_ns())
        self._gateway.feed(event)
        chunk = event.chunk
        self._window.answered(chunk.observation_id if isinstance(chunk, Chunk) else None)
