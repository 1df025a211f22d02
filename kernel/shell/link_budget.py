"""When the shell spends its time on a policy peer's chunks: the admission pacer.

The rates, the window of requests in flight and the chunk queue are the protocol object's
decisions, made on times passed in (:mod:`kernel.shell.link_protocol_budget`, re-exported here).
What stays in the shell is where in the control period an admission runs, which only the
control loop knows: :class:`AdmissionPacer` grants at most so many chunk admissions per control
period, started either right after the period's tick or while at least half of the period
remains, so that an admission (about half a millisecond, docs/architecture.md) ends before the
next deadline.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

from kernel.shell.link_protocol_budget import RequestWindow, TokenBucket

__all__ = ["AdmissionPacer", "RequestWindow", "TokenBucket"]


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
