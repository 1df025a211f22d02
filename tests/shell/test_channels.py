"""Bounded channels: bounds, drop-oldest, backpressure, close semantics, statistics."""

from __future__ import annotations

import asyncio
import dataclasses

import pytest
from hypothesis import given
from hypothesis import strategies as st

from kernel.shell.channels import (
    Channel,
    ChannelClosed,
    EndOfChannel,
    Policy,
    WouldBlock,
)


async def _settle() -> None:
    """Let every ready task run until it parks (a few loop iterations, no wall clock)."""
    for _ in range(5):
        await asyncio.sleep(0)


def test_a_channel_is_always_bounded() -> None:
    for bad in (0, -1):
        with pytest.raises(ValueError, match="bounded"):
            Channel(bad)
    with pytest.raises(ValueError):
        Channel(4, "unbounded")


def test_block_policy_refuses_when_full() -> None:
    channel: Channel[int] = Channel(2, Policy.BLOCK)
    channel.send_nowait(1)
    channel.send_nowait(2)
    with pytest.raises(WouldBlock):
        channel.send_nowait(3)
    stats = channel.statistics()
    assert (stats.size, stats.peak_size, stats.sent, stats.dropped) == (2, 2, 2, 0)


def test_drop_oldest_keeps_the_newest() -> None:
    channel: Channel[int] = Channel(3, "drop_oldest")
    for item in range(10):
        channel.send_nowait(item)
    assert channel.drain_nowait(100) == [7, 8, 9]
    stats = channel.statistics()
    assert (stats.sent, stats.received, stats.dropped, stats.peak_size, stats.size) == (
        10, 3, 7, 3, 0)
    assert stats.max_size == 3


@given(st.integers(1, 8), st.lists(st.integers(), max_size=40))
def test_drop_oldest_accounting(maxsize: int, items: list[int]) -> None:
    channel: Channel[int] = Channel(maxsize, Policy.DROP_OLDEST)
    for item in items:
        channel.send_nowait(item)
    stats = channel.statistics()
    assert channel.drain_nowait(maxsize) == items[-maxsize:]
    assert stats.sent == stats.size + stats.dropped + stats.received
    assert stats.peak_size == min(maxsize, len(items))


def test_statistics_are_frozen() -> None:
    stats = Channel(1).statistics()
    with pytest.raises(dataclasses.FrozenInstanceError):
        stats.size = 5  # type: ignore[misc]


async def test_backpressure_blocks_the_sender_until_room() -> None:
    channel: Channel[int] = Channel(1, Policy.BLOCK)
    received: list[int] = []

    async def sender() -> None:
        for item in range(3):
            await channel.send(item)

    async with asyncio.TaskGroup() as group:
        group.create_task(sender())
        await _settle()
        assert len(channel) == 1
        assert channel.statistics().waiting_senders == 1
        for _ in range(3):
            received.append(await channel.receive())
    assert received == [0, 1, 2]
    assert channel.statistics().peak_size == 1


async def test_drop_oldest_send_never_waits() -> None:
    channel: Channel[int] = Channel(1, Policy.DROP_OLDEST)
    for item in range(5):
        await channel.send(item)
    assert channel.receive_nowait() == 4
    assert channel.statistics().dropped == 4


async def test_close_drains_then_ends() -> None:
    channel: Channel[str] = Channel(4)
    channel.send_nowait("a")
    channel.send_nowait("b")
    channel.close()
    channel.close()
    with pytest.raises(ChannelClosed):
        channel.send_nowait("c")
    with pytest.raises(ChannelClosed):
        await channel.send("c")
    assert [item async for item in channel] == ["a", "b"]
    with pytest.raises(EndOfChannel):
        await channel.receive()
    with pytest.raises(EndOfChannel):
        channel.receive_nowait()
    assert channel.statistics().closed


async def test_close_wakes_blocked_senders_and_receivers() -> None:
    full: Channel[int] = Channel(1)
    full.send_nowait(0)
    empty: Channel[int] = Channel(1)
    outcomes: list[str] = []

    async def blocked_sender() -> None:
        with pytest.raises(ChannelClosed):
            await full.send(1)
        outcomes.append("sender")

    async def blocked_receiver() -> None:
        with pytest.raises(EndOfChannel):
            await empty.receive()
        outcomes.append("receiver")

    async with asyncio.TaskGroup() as group:
        group.create_task(blocked_sender())
        group.create_task(blocked_receiver())
        await _settle()
        full.close()
        empty.close()
    assert sorted(outcomes) == ["receiver", "sender"]
    assert full.receive_nowait() == 0


async def test_receive_waits_for_a_send() -> None:
    channel: Channel[int] = Channel(2)
    async with asyncio.TaskGroup() as group:
        receiving = group.create_task(channel.receive())
        await _settle()
        assert channel.statistics().waiting_receivers == 1
        channel.send_nowait(42)
    assert receiving.result() == 42


async def test_a_wakeup_is_not_lost_when_the_woken_receiver_is_cancelled() -> None:
    channel: Channel[int] = Channel(2)
    async with asyncio.TaskGroup() as group:
        first = group.create_task(channel.receive())
        second = group.create_task(channel.receive())
        await _settle()
        channel.send_nowait(7)  # wakes `first` ...
        first.cancel()  # ... which is cancelled before it runs: `second` must get the item
    assert first.cancelled()
    assert second.result() == 7


async def test_drain_wakes_blocked_senders() -> None:
    channel: Channel[int] = Channel(2)
    async with asyncio.TaskGroup() as group:
        channel.send_nowait(0)
        channel.send_nowait(1)
        group.create_task(channel.send(2))
        group.create_task(channel.send(3))
        await _settle()
        assert channel.drain_nowait(5) == [0, 1]
    assert channel.drain_nowait(5) == [2, 3]
    assert channel.drain_nowait(5) == []
