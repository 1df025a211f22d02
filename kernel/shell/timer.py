"""Fixed-rate timers for the control loop: a Linux timerfd one and a virtual one for lockstep runs.

asyncio and libuv timers have whole-millisecond resolution (bench/loop.py measures it),
which is a third of a 500 Hz period. A timerfd armed at an absolute CLOCK_MONOTONIC deadline and
watched with ``loop.add_reader`` wakes the loop within microseconds, on the stock loop and on
uvloop alike. Optionally it fires ``early_ns`` before the deadline and busy-waits the remainder,
so a callback that happens to be queued in front of the tick does not delay it.

Skipping, never catching up: a tick is labelled with the latest deadline that has passed when it
wakes. Deadlines that passed without a tick are counted in ``Tick.skipped``; they are never
replayed as a burst of back-to-back ticks.
"""

from __future__ import annotations

import asyncio
import ctypes
import os
import time
from dataclasses import dataclass
from types import TracebackType
from typing import Protocol, Self

CLOCK_MONOTONIC = 1
TFD_NONBLOCK = os.O_NONBLOCK
TFD_CLOEXEC = os.O_CLOEXEC
TFD_TIMER_ABSTIME = 1
_NS = 1_000_000_000


class TimerClosedError(RuntimeError):
    """The timer was used after ``close()``, or closed while a ``wait()`` was pending."""


@dataclass(frozen=True, slots=True)
class Tick:
    """One wake-up of a periodic timer.

    ``index`` counts periods from the timer's start (deadline ``start_ns + index * period_ns``);
    ``skipped`` is how many deadlines passed without a tick since the previous one, so
    ``index == previous.index + 1 + skipped``. ``lateness_ns`` is ``woke_ns - deadline_ns``,
    in ``[0, period_ns)`` for the timers of this module; the lateness against the first
    deadline that was not served is ``lateness_ns + skipped * period_ns``.
    """

    index: int
    deadline_ns: int
    woke_ns: int
    lateness_ns: int
    skipped: int


class Clock(Protocol):
    def now_ns(self) -> int: ...


class MonotonicClock:
    """CLOCK_MONOTONIC, the clock a timerfd is armed against."""

    def now_ns(self) -> int:
        return time.monotonic_ns()


class VirtualClock:
    """A clock that moves only when told to: replay and lockstep tests."""

    def __init__(self, start_ns: int = 0) -> None:
        self._now = start_ns

    def now_ns(self) -> int:
        return self._now

    def advance(self, delta_ns: int) -> None:
        if delta_ns < 0:
            raise ValueError(f"a clock cannot go back ({delta_ns} ns)")
        self._now += delta_ns

    def advance_to(self, t_ns: int) -> None:
        self.advance(max(0, t_ns - self._now))


class Timer(Protocol):
    """What the control loop needs from a timer (both timers below implement it)."""

    period_ns: int

    async def wait(self) -> Tick: ...

    def close(self) -> None: ...


class Schedule:
    """Pure deadline arithmetic shared by the timers (no clock, no I/O).

    ``take(woke_ns)`` labels a wake-up with the latest deadline at or before it and counts the
    deadlines skipped since the previous tick. A wake-up before the next deadline (only a timer
    that wakes early, such as a plain ``asyncio.sleep``, does that) gets a negative lateness.
    """

    def __init__(self, period_ns: int, start_ns: int) -> None:
        if period_ns <= 0:
            raise ValueError(f"period_ns must be positive, got {period_ns}")
        self.period_ns = period_ns
        self.start_ns = start_ns
        self.next_index = 0  # first deadline not yet served by a tick

    def deadline(self, index: int) -> int:
        return self.start_ns + index * self.period_ns

    @property
    def next_deadline_ns(self) -> int:
        return self.deadline(self.next_index)

    def take(self, woke_ns: int) -> Tick:
        """Label a wake-up at ``woke_ns`` and move past its deadline."""
        latest = (woke_ns - self.start_ns) // self.period_ns
        index = max(latest, self.next_index)
        deadline = self.deadline(index)
        tick = Tick(index=index, deadline_ns=deadline, woke_ns=woke_ns,
                    lateness_ns=woke_ns - deadline, skipped=index - self.next_index)
        self.next_index = index + 1
        return tick


class _ITimerSpec(ctypes.Structure):
    # struct itimerspec { struct timespec it_interval, it_value; }, time_t and long are 64-bit.
    _fields_ = [("interval_sec", ctypes.c_long), ("interval_nsec", ctypes.c_long),
                ("value_sec", ctypes.c_long), ("value_nsec", ctypes.c_long)]


def _libc() -> ctypes.CDLL:
    libc = ctypes.CDLL(None, use_errno=True)
    libc.timerfd_create.argtypes = [ctypes.c_int, ctypes.c_int]
    libc.timerfd_create.restype = ctypes.c_int
    libc.timerfd_settime.argtypes = [ctypes.c_int, ctypes.c_int,
                                     ctypes.POINTER(_ITimerSpec), ctypes.c_void_p]
    libc.timerfd_settime.restype = ctypes.c_int
    return libc


_LIBC = _libc()


def _check(result: int, what: str) -> int:
    if result < 0:
        errno = ctypes.get_errno()
        raise OSError(errno, f"{what}: {os.strerror(errno)}")
    return result


class PeriodicTimer:
    """A fixed-rate timer on a timerfd, for any asyncio loop on Linux.

    Use as ``async with PeriodicTimer(2_000_000, early_ns=200_000) as timer:`` then
    ``tick = await timer.wait()`` in the control loop. One waiter at a time.
    ``wait()`` returns without yielding when the next deadline has already passed.
    """

    def __init__(self, period_ns: int, *, early_ns: int = 0, start_ns: int | None = None) -> None:
        if not 0 <= early_ns < period_ns:
            raise ValueError(f"early_ns must be in [0, period_ns), got {early_ns}")
        self.period_ns = period_ns
        self.early_ns = early_ns
        self._start_ns = start_ns
        self._schedule: Schedule | None = None
        self._fd = -1
        self._loop: asyncio.AbstractEventLoop | None = None
        self._waiter: asyncio.Future[None] | None = None
        self._spec = _ITimerSpec()  # reused: no allocation per tick
        self._closed = False

    @property
    def fileno(self) -> int:
        return self._fd

    def open(self) -> None:
        """Create the timerfd and register it with the running loop."""
        if self._closed or self._fd >= 0:
            raise TimerClosedError("a PeriodicTimer opens once")
        loop = asyncio.get_running_loop()
        start = self._start_ns
        if start is None:
            start = time.monotonic_ns() + self.period_ns
        self._schedule = Schedule(self.period_ns, start)
        self._fd = _check(_LIBC.timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC),
                          "timerfd_create")
        try:
            loop.add_reader(self._fd, self._on_readable)
        except BaseException:
            os.close(self._fd)  # e.g. a loop without add_reader: do not leak the fd
            self._fd = -1
            raise
        self._loop = loop

    async def wait(self) -> Tick:
        schedule = self._require_open()
        deadline = schedule.next_deadline_ns
        fire_at = deadline - self.early_ns
        while time.monotonic_ns() < fire_at:
            await self._sleep_until(fire_at)
        # Fired early on purpose: spin the last stretch on the loop thread for microsecond wake.
        while (now := time.monotonic_ns()) < deadline:
            pass
        return schedule.take(now)

    def close(self) -> None:
        """Remove the reader and close the fd; safe to call twice."""
        self._closed = True
        if self._fd < 0:
            return
        fd, self._fd = self._fd, -1
        if self._loop is not None and not self._loop.is_closed():
            self._loop.remove_reader(fd)
        os.close(fd)
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_exception(TimerClosedError("timer closed while waiting"))

    async def aclose(self) -> None:
        self.close()

    async def __aenter__(self) -> Self:
        self.open()
        return self

    async def __aexit__(self, et: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> None:
        self.close()

    def _require_open(self) -> Schedule:
        if self._closed or self._schedule is None:
            raise TimerClosedError("PeriodicTimer is closed or was never opened")
        if self._waiter is not None and not self._waiter.done():
            raise RuntimeError("PeriodicTimer.wait() is already being awaited")
        return self._schedule

    async def _sleep_until(self, t_ns: int) -> None:
        self._arm(t_ns)
        loop = self._loop
        if loop is None:
            raise TimerClosedError("PeriodicTimer is not open")
        self._waiter = loop.create_future()
        try:
            await self._waiter
        finally:
            self._waiter = None

    def _arm(self, t_ns: int) -> None:
        spec = self._spec
        spec.value_sec, spec.value_nsec = divmod(t_ns, _NS)
        _check(_LIBC.timerfd_settime(self._fd, TFD_TIMER_ABSTIME, ctypes.byref(spec), None),
               "timerfd_settime")

    def _on_readable(self) -> None:
        if self._fd < 0:
            return  # readiness queued in the same loop iteration as close()
        try:
            os.read(self._fd, 8)  # the expiration count; the schedule counts skips itself
        except BlockingIOError:
            return  # re-arming reset the count after readiness was queued: not a wake-up
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_result(None)


class VirtualTimer:
    """Same interface as :class:`PeriodicTimer` on a :class:`VirtualClock`.

    ``wait()`` moves the clock straight to the next deadline (if it is not already past it)
    and yields once to the loop, so lockstep runs are instant and bit-for-bit repeatable.
    """

    def __init__(self, period_ns: int, *, clock: VirtualClock, early_ns: int = 0,
                 start_ns: int | None = None) -> None:
        start = start_ns if start_ns is not None else clock.now_ns() + period_ns
        self.period_ns = period_ns
        self.early_ns = early_ns  # accepted for interface parity; a virtual clock is exact
        self.clock = clock
        self._schedule = Schedule(period_ns, start)
        self._closed = False

    def open(self) -> None:
        if self._closed:
            raise TimerClosedError("a VirtualTimer opens once")

    async def wait(self) -> Tick:
        if self._closed:
            raise TimerClosedError("VirtualTimer is closed")
        self.clock.advance_to(self._schedule.next_deadline_ns)
        await asyncio.sleep(0)  # a checkpoint, so lockstep peers run between ticks
        return self._schedule.take(self.clock.now_ns())

    def close(self) -> None:
        self._closed = True

    async def aclose(self) -> None:
        self.close()

    async def __aenter__(self) -> Self:
        self.open()
        return self

    async def __aexit__(self, et: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> None:
        self.close()
