"""PeriodicTimer (timerfd) and VirtualTimer: counts and ordering, never wall-clock bounds."""

from __future__ import annotations

import asyncio
import os
import time

import pytest

from kernel.shell.timer import (
    MonotonicClock,
    PeriodicTimer,
    Tick,
    TimerClosedError,
    VirtualClock,
    VirtualTimer,
)

PERIOD = 2_000_000  # 500 Hz


def _check_consistent(ticks: list[Tick], start_ns: int, period_ns: int) -> None:
    previous = -1
    for tick in ticks:
        assert tick.index == previous + 1 + tick.skipped
        assert tick.deadline_ns == start_ns + tick.index * period_ns
        assert tick.lateness_ns == tick.woke_ns - tick.deadline_ns
        assert 0 <= tick.lateness_ns < period_ns
        previous = tick.index


def _fds() -> set[str]:
    return set(os.listdir("/proc/self/fd"))


@pytest.mark.parametrize("early_ns", [0, 300_000])
async def test_periodic_timer_ticks_in_order(early_ns: int) -> None:
    start = time.monotonic_ns() + PERIOD
    async with PeriodicTimer(PERIOD, early_ns=early_ns, start_ns=start) as timer:
        ticks = [await timer.wait() for _ in range(20)]
    _check_consistent(ticks, start, PERIOD)
    assert [t.woke_ns for t in ticks] == sorted(t.woke_ns for t in ticks)
    assert ticks[0].index >= 0


async def test_blocked_loop_skips_periods_and_never_bursts() -> None:
    start = time.monotonic_ns() + PERIOD
    async with PeriodicTimer(PERIOD, start_ns=start) as timer:
        first = await timer.wait()
        time.sleep(3.5 * PERIOD / 1e9)  # block the loop thread for 3.5 periods
        late = await timer.wait()
        after = await timer.wait()
    # At least deadlines first+1 .. first+3 passed while blocked: the tick serves the latest.
    assert late.skipped >= 2
    assert late.index == first.index + 1 + late.skipped
    # No catch-up burst: the next deadline is one after the late tick's wake-up.
    assert after.deadline_ns > late.woke_ns
    _check_consistent([first, late, after], start, PERIOD)


async def test_close_releases_the_fd_and_is_idempotent() -> None:
    before = _fds()
    timer = PeriodicTimer(PERIOD)
    timer.open()
    fd = timer.fileno
    assert "timerfd" in os.readlink(f"/proc/self/fd/{fd}")
    await timer.wait()
    timer.close()
    timer.close()
    assert _fds() == before
    with pytest.raises(TimerClosedError):
        await timer.wait()
    with pytest.raises(TimerClosedError):
        timer.open()


async def test_close_wakes_a_pending_wait() -> None:
    outcome: list[str] = []

    async def waiter(timer: PeriodicTimer) -> None:
        with pytest.raises(TimerClosedError):
            await timer.wait()
        outcome.append("woken by close")

    async with PeriodicTimer(10**9) as timer, asyncio.TaskGroup() as group:
        group.create_task(waiter(timer))
        await asyncio.sleep(0)
        timer.close()
    assert outcome == ["woken by close"]


async def test_cancelled_wait_leaves_the_timer_usable() -> None:
    start = time.monotonic_ns() + 10 * PERIOD  # far enough that the first wait() must block
    async with PeriodicTimer(PERIOD, start_ns=start) as timer:
        with pytest.raises(TimeoutError):
            async with asyncio.timeout(0):
                await timer.wait()
        ticks = [await timer.wait() for _ in range(3)]
    _check_consistent(ticks, start, PERIOD)


async def test_one_waiter_at_a_time() -> None:
    async with PeriodicTimer(10**9) as timer, asyncio.TaskGroup() as group:
        first = group.create_task(timer.wait())
        await asyncio.sleep(0)
        with pytest.raises(RuntimeError, match="already"):
            await timer.wait()
        first.cancel()


def test_invalid_arguments() -> None:
    with pytest.raises(ValueError):
        PeriodicTimer(0)
    with pytest.raises(ValueError):
        PeriodicTimer(PERIOD, early_ns=PERIOD)
    with pytest.raises(ValueError):
        VirtualClock().advance(-1)


async def _virtual_run() -> list[Tick]:
    clock = VirtualClock(start_ns=1_000)
    ticks = []
    async with VirtualTimer(PERIOD, clock=clock) as timer:
        for step in range(6):
            ticks.append(await timer.wait())
            assert clock.now_ns() == ticks[-1].deadline_ns or step == 3
            if step == 2:
                clock.advance(3 * PERIOD + PERIOD // 2)  # a slow step: 3.5 periods
    return ticks


async def test_virtual_timer_is_deterministic() -> None:
    first, second = await _virtual_run(), await _virtual_run()
    assert first == second
    _check_consistent(first, 1_000 + PERIOD, PERIOD)
    assert [t.skipped for t in first] == [0, 0, 0, 2, 0, 0]
    assert first[3].lateness_ns == PERIOD // 2
    assert all(t.lateness_ns == 0 for i, t in enumerate(first) if i != 3)


async def test_virtual_timer_closes() -> None:
    timer = VirtualTimer(PERIOD, clock=VirtualClock())
    timer.close()
    with pytest.raises(TimerClosedError):
        await timer.wait()


def test_monotonic_clock_moves_forward() -> None:
    clock = MonotonicClock()
    assert clock.now_ns() <= clock.now_ns()
