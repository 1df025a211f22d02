"""Bounded in-process channels with trio-style statistics.

Two policies, chosen per channel: ``block`` gives backpressure (commands must never be lost, so
a full channel makes the sender wait) and ``drop_oldest`` keeps the newest items (telemetry:
a slow consumer must never slow the control loop, and fresh samples beat stale ones). There is
no unbounded mode. ``statistics()`` returns a frozen snapshot, including the peak size and the
number of dropped items, so a dashboard can tell a healthy channel from a saturated one.
"""

from __future__ import annotations

import asyncio
import collections
from collections.abc import AsyncIterator
from contextlib import suppress
from dataclasses import dataclass
from enum import StrEnum
from typing import Generic, TypeVar

T = TypeVar("T")


class Policy(StrEnum):
    BLOCK = "block"
    DROP_OLDEST = "drop_oldest"


class WouldBlock(Exception):
    """A ``*_nowait`` call would have had to wait."""


class ChannelClosed(Exception):
    """Sending on a closed channel (also raised to senders blocked when it closes)."""


class EndOfChannel(Exception):
    """The channel is closed and drained: nothing more will arrive."""


@dataclass(frozen=True, slots=True)
class ChannelStatistics:
    size: int
    peak_size: int
    max_size: int
    sent: int
    received: int
    dropped: int
    closed: bool
    waiting_senders: int
    waiting_receivers: int


class Channel(Generic[T]):
    """A bounded FIFO between tasks on one event loop (not thread-safe, like asyncio.Queue)."""

    def __init__(self, maxsize: int, policy: Policy | str = Policy.BLOCK) -> None:
        if maxsize < 1:
            raise ValueError(f"a channel is bounded: maxsize must be >= 1, got {maxsize}")
        self.maxsize = maxsize
        self.policy = Policy(policy)
        self._items: collections.deque[T] = collections.deque()
        self._senders: collections.deque[asyncio.Future[None]] = collections.deque()
        self._receivers: collections.deque[asyncio.Future[None]] = collections.deque()
        self._closed = False
        self._peak = self._sent = self._received = self._dropped = 0

    # -- sending -------------------------------------------------------------------------------
    def send_nowait(self, item: T) -> None:
        """Send without waiting.

        Raises:
            ChannelClosed: the channel is closed.
            WouldBlock: the channel is full and its policy is ``block``.
        """
        if self._closed:
            raise ChannelClosed("send on a closed channel")
        if len(self._items) >= self.maxsize:
            if self.policy is Policy.BLOCK:
                raise WouldBlock(f"channel full ({self.maxsize})")
            self._items.popleft()
            self._dropped += 1
        self._put(item)

    async def send(self, item: T) -> None:
        """Send, waiting for room under ``block``; never waits under ``drop_oldest``."""
        while self.policy is Policy.BLOCK and len(self._items) >= self.maxsize:
            if self._closed:
                break
            await self._park(self._senders)
        self.send_nowait(item)

    # -- receiving -----------------------------------------------------------------------------
    def receive_nowait(self) -> T:
        """Take the oldest item.

        Raises:
            EndOfChannel: the channel is closed and empty.
            WouldBlock: the channel is open and empty.
        """
        if not self._items:
            raise EndOfChannel() if self._closed else WouldBlock("channel empty")
        return self._take()

    async def receive(self) -> T:
        """Wait for an item; raises :class:`EndOfChannel` once closed and drained."""
        while not self._items and not self._closed:
            await self._park(self._receivers)
        return self.receive_nowait()

    def drain_nowait(self, limit: int) -> list[T]:
        """Take up to ``limit`` items without waiting (a batch for an encoder); may be empty."""
        batch = [self._items.popleft() for _ in range(min(limit, len(self._items)))]
        self._received += len(batch)
        if batch:
            self._wake(self._senders, len(batch))
        return batch

    def __aiter__(self) -> AsyncIterator[T]:
        return self

    async def __anext__(self) -> T:
        try:
            return await self.receive()
        except EndOfChannel:
            raise StopAsyncIteration from None

    # -- lifecycle -----------------------------------------------------------------------------
    def close(self) -> None:
        """Stop accepting items; receivers still drain what is buffered. Idempotent."""
        self._closed = True
        self._wake(self._senders, len(self._senders))
        self._wake(self._receivers, len(self._receivers))

    @property
    def closed(self) -> bool:
        return self._closed

    def __len__(self) -> int:
        return len(self._items)

    def statistics(self) -> ChannelStatistics:
        return ChannelStatistics(
            size=len(self._items), peak_size=self._peak, max_size=self.maxsize,
            sent=self._sent, received=self._received, dropped=self._dropped,
            closed=self._closed, waiting_senders=len(self._senders),
            waiting_receivers=len(self._receivers))

    # -- internals -----------------------------------------------------------------------------
    def _put(self, item: T) -> None:
        self._items.append(item)
        self._sent += 1
        self._peak = max(self._peak, len(self._items))
        self._wake(self._receivers, 1)

    def _take(self) -> T:
        item = self._items.popleft()
        self._received += 1
        self._wake(self._senders, 1)
        return item

    @staticmethod
    def _wake(waiters: collections.deque[asyncio.Future[None]], count: int) -> None:
        while count > 0 and waiters:
            waiter = waiters.popleft()
            if not waiter.done():
                waiter.set_result(None)
                count -= 1

    async def _park(self, waiters: collections.deque[asyncio.Future[None]]) -> None:
        waiter = asyncio.get_running_loop().create_future()
        waiters.append(waiter)
        try:
            await waiter
        except BaseException:
            waiter.cancel()
            with suppress(ValueError):
                waiters.remove(waiter)
            if waiter.done() and not waiter.cancelled():
                # Woken and cancelled in the same step: pass the wake-up on, or it is lost.
                self._wake(waiters, 1)
            raise
