"""The policy link's admission pump: waiting chunks fed to the core one admission slot at a time.

Which chunks wait, and which are dropped, is the protocol object's decision (its chunk queue:
:class:`~kernel.shell.link_protocol_budget.ChunkQueue`). What stays in the shell is when an
admission runs: at a slot the control loop hands out (:class:`~kernel.shell.link_budget.
AdmissionPacer`), or at least never two without yielding to the event loop. The protocol decodes
each chunk only then, stamped with the instant it is decided; what the core decided on it reaches
the link as a typed :class:`~kernel.core.effects.ChunkDecision` (whichever event decided it: the
chunk's own, or its job's result).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from kernel.shell.link_budget import AdmissionPacer
from kernel.shell.link_protocol import LinkProtocol, Output
from kernel.shell.link_protocol_budget import OTHERS_QUEUED
from kernel.shell.link_types import LinkCounters

__all__ = ["OTHERS_QUEUED", "ChunkIntake"]


class ChunkIntake:
    def __init__(self, protocol: LinkProtocol, counters: LinkCounters,
                 pacer: AdmissionPacer | None, now_ns: Callable[[], int],
                 apply: Callable[[list[Output]], None]) -> None:
        self._protocol, self._counters, self._pacer = protocol, counters, pacer
        self._now_ns, self._apply = now_ns, apply
        self._arrived = asyncio.Event()

    def wake(self) -> None:
        """A chunk is waiting (:class:`~kernel.shell.link_protocol.ChunksWaiting`)."""
        self._arrived.set()

    async def run(self) -> None:
        """Feed waiting chunks to the core, one admission slot at a time (until cancelled)."""
        while True:
            while not self._protocol.chunks_waiting:
                self._arrived.clear()
                await self._arrived.wait()
            if self._pacer is None:
                await asyncio.sleep(0)  # still never two admissions without yielding
            else:
                await self._pacer.slot()
                self._counters.admissions_deferred = self._pacer.deferred
            # decided now, decoded now: the core's clock only moves forward
            self._apply(self._protocol.next_chunk(self._now_ns()))
