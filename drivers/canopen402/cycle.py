"""The bus cycle: every drive's RPDO, then one SYNC, once per control period.

While the control loop streams, ``write`` ends each cycle itself (``tick``), so the SYNC is in
phase with the loop and every setpoint reaches the drives exactly once; a free-running SYNC
thread at the same nominal rate would beat against the loop and now and then apply one setpoint
twice and skip the next. When nobody writes (INACTIVE, during state changes, or a loop that
stalled) a keeper thread ticks on its own at the control period, because synchronous TPDOs, and
so every reading, stop without SYNC.

The cycle also records, per SYNC, when the last drive's TPDOs came back: the round-trip latency
of a control cycle, and whether it finished before the next SYNC.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections import deque
from collections.abc import Sequence

import can

from drivers.canopen402._sdk import Network, PdoMap

KEEPER_GRACE = 1.5
"""While ``write`` drives the cycle, the keeper steps in only after this many quiet periods."""
KEEPER_PATIENCE = 4
KEEPER_MIN_PATIENCE_S = 0.02
"""The keeper waits this many periods, and at least this long, for an unanswered SYNC before
it sends the next one (at 1 kHz, four periods are shorter than a slow host's round trip)."""


class BusCycle:
    def __init__(self, network: Network, rpdos: Sequence[PdoMap],
                 tpdo_keys: Sequence[tuple[int, int]], period_s: float) -> None:
        self.period_s = period_s
        self._network = network
        self._rpdos = tuple(rpdos)
        self._tpdo_keys = frozenset(tpdo_keys)
        self._send_lock = threading.Lock()
        self._state_lock = threading.Lock()
        self._stop = threading.Event()
        self._keeper: threading.Thread | None = None
        self._last_tick = 0.0
        self._next_due = 0.0
        self._patience_s = max(KEEPER_PATIENCE * period_s, KEEPER_MIN_PATIENCE_S)
        self._pending: set[tuple[int, int]] = set()
        self._sent_ns = 0
        self.cycle = 0
        self.completed = 0
        self.overruns = 0
        self.latencies_ns: deque[int] = deque(maxlen=4096)
        self.error: can.CanError | None = None
        self._waiters: list[tuple[asyncio.AbstractEventLoop, asyncio.Future[None], int]] = []

    # -- producing -----------------------------------------------------------------------------

    def start(self) -> None:
        self._keeper = threading.Thread(target=self._keep, name="canopen-sync", daemon=True)
        self._keeper.start()

    def stop(self) -> None:
        self._stop.set()
        if self._keeper is not None and self._keeper is not threading.current_thread():
            self._keeper.join(timeout=1.0)

    def tick(self, from_write: bool = False) -> int:
        """Send every RPDO, then SYNC; returns the number of this cycle.

        Raises:
            can.CanError: the bus refused a frame (the caller maps it to LINK_LOST).
        """
        with self._send_lock:
            self._open_cycle()
            for rpdo in self._rpdos:
                rpdo.transmit()
            self._network.sync.transmit()
            self._last_tick = time.monotonic()
            self._schedule_next(from_write)
            return self.cycle

    def _schedule_next(self, from_write: bool) -> None:
        """When the keeper is the producer it keeps absolute deadlines, so that send time and
        timer slack do not stretch every period; a write re-anchors it to the control loop."""
        if from_write:
            self._next_due = self._last_tick + KEEPER_GRACE * self.period_s
            return
        self._next_due += self.period_s
        if self._next_due < self._last_tick:  # fell behind (a stall): no burst to catch up
            self._next_due = self._last_tick + self.period_s

    def _open_cycle(self) -> None:
        with self._state_lock:
            if self._pending:
                self.overruns += 1  # the previous SYNC's TPDOs are not all back yet
            self.cycle += 1
            self._pending = set(self._tpdo_keys)
            self._sent_ns = time.monotonic_ns()

    def _keep(self) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            if now < self._next_due:
                self._stop.wait(self._next_due - now)
            elif self._unanswered() and now < self._last_tick + self._patience_s:
                # Backpressure: a keep-alive SYNC while the last one is unanswered only piles
                # frames up in a drive (or an emulator) that is behind.
                self._stop.wait(self.period_s / 4)
            else:
                self._keep_alive()

    def _keep_alive(self) -> None:
        try:
            self.tick()
        except can.CanError as error:
            self.error = error  # reported by the next read or write, on the loop
            self._stop.wait(self.period_s)

    def _unanswered(self) -> bool:
        with self._state_lock:
            return bool(self._pending)

    # -- completing ----------------------------------------------------------------------------

    def on_tpdo(self, node_id: int, cob_id: int) -> None:
        """A TPDO arrived (frame dispatch thread)."""
        with self._state_lock:
            if not self._pending:
                return
            self._pending.discard((node_id, cob_id))
            if self._pending:
                return
            self.completed = self.cycle
            self.latencies_ns.append(time.monotonic_ns() - self._sent_ns)
            waiters = [w for w in self._waiters if w[2] <= self.completed]
            self._waiters = [w for w in self._waiters if w[2] > self.completed]
        for loop, future, _ in waiters:
            loop.call_soon_threadsafe(_resolve, future)

    async def wait_completed(self, cycle: int, timeout_s: float) -> bool:
        """Wait until every TPDO answering SYNC number ``cycle`` has arrived."""
        loop = asyncio.get_running_loop()
        future: asyncio.Future[None] = loop.create_future()
        with self._state_lock:
            if self.completed >= cycle:
                return True
            self._waiters.append((loop, future, cycle))
        try:
            async with asyncio.timeout(timeout_s):
                await future
            return True
        except TimeoutError:
            return False


def _resolve(future: asyncio.Future[None]) -> None:
    if not future.done():
        future.set_result(None)
