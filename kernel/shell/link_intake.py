"""The policy link's chunk intake: from a chunk frame to a chunk event, at a bounded cost.

A chunk frame is queued if it is the first to cite an observation in flight (the answer the robot
waits for: read from the frame with a decoder that skips everything else; it is admitted before
any other), or else if the chunk rate allows it and fewer than :data:`OTHERS_QUEUED` others are
waiting; any other is dropped and counted, never fed. An admission task then feeds the queued
chunks to the core one admission slot at a time (:class:`~kernel.shell.link_budget.
AdmissionPacer`), decoding each only then, stamped with the instant it is decided. What the core
decided goes back into the link's counters and its window of requests in flight.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable

import msgspec

from assurance.envelope import Chunk, MalformedChunk, decode_wire_chunk
from kernel.core import events as ev
from kernel.core.lines import ChunkLine
from kernel.shell.link_budget import AdmissionPacer, RequestWindow, TokenBucket
from kernel.shell.link_types import Gateway, LinkCounters
from kernel.summary import ADMITTED
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
                 on_admitted: Callable[[], None]) -> None:
        self._gateway, self._counters, self._window = gateway, counters, window
        self._pacer, self._on_admitted = pacer, on_admitted
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
        t = self._gateway.now_ns()  # decided now: the core's clock only moves forward
        chunk = decode_wire_chunk(frame.body, t)
        counters = self._counters
        if isinstance(chunk, MalformedChunk):
            counters.malformed += 1
        for line in self._gateway.feed(ev.ChunkEvent(t, chunk, bytes(frame.body))).lines:
            if isinstance(line, ChunkLine):
                admitted = line.decision in ADMITTED
                if admitted:
                    self._on_admitted()
                counters.chunks_admitted += admitted
                counters.chunks_refused += not admitted
        self._window.answered(chunk.observation_id if isinstance(chunk, Chunk) else None)
