"""The kernel-owned lifecycle around every driver (ros2_control's hardware component, in Python).

States: UNCONFIGURED → INACTIVE (connected and configured) → ACTIVE (streaming) → back to
INACTIVE, and FAULT or CLOSED from anywhere (what each allows: :class:`drivers.base.Driver`).
The wrapper calls ``write`` only when ACTIVE and only with a kind the driver declares, turns
any exception into FAULT with the error's reason code, and records the duration of every call.
"""

from __future__ import annotations

import contextlib
import time
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import TypeVar

import msgspec

from assurance.reasons import ReasonCode
from drivers.base import (
    Applied,
    Command,
    CommandKind,
    ControlConfig,
    Driver,
    DriverError,
    DriverState,
    StateSample,
)

T = TypeVar("T")


@dataclass(slots=True)
class CallStats:
    """Durations of one kind of call, in nanoseconds, over a bounded window."""

    window: int = 2048
    count: int = 0
    failures: int = 0
    last_ns: int = 0
    max_ns: int = 0
    recent: deque[int] = field(default_factory=deque)

    def record(self, duration_ns: int, ok: bool) -> None:
        self.count += 1
        self.failures += 0 if ok else 1
        self.last_ns = duration_ns
        self.max_ns = max(self.max_ns, duration_ns)
        self.recent.append(duration_ns)
        if len(self.recent) > self.window:
            self.recent.popleft()

    def percentile(self, p: float) -> int:
        if not self.recent:
            return 0
        ordered = sorted(self.recent)
        return ordered[min(len(ordered) - 1, int(p / 100.0 * len(ordered)))]


class LifecycleError(RuntimeError):
    """A lifecycle call made in a state that does not allow it."""


class ManagedDriver:
    """Owns the state of one driver; the only object the kernel talks to."""

    def __init__(self, driver: Driver) -> None:
        self.driver = driver
        self.state = DriverState.UNCONFIGURED
        self.fault: ReasonCode | None = None
        self.fault_detail = ""
        self.stats: dict[str, CallStats] = {}
        self.last_sample: StateSample | None = None
        self.last_ok_ns = 0

    @property
    def name(self) -> str:
        return self.driver.name

    async def configure(self, control: ControlConfig) -> None:
        """UNCONFIGURED → INACTIVE: connect and configure the device."""
        self._require(DriverState.UNCONFIGURED, "configure")
        await self._call("connect", self.driver.connect())
        await self._call("configure", self.driver.configure(control))
        self.state = DriverState.INACTIVE

    async def activate(self) -> None:
        self._require(DriverState.INACTIVE, "activate")
        await self._call("activate", self.driver.activate())
        self.state = DriverState.ACTIVE

    async def before_first_tick(self) -> None:
        """The driver's ``before_first_tick`` hook (drivers/base.py), in ACTIVE only.

        A failure is a fault like a failed read or write (recorded here, seen by the core in
        the next sample: CONTROLLER_STOP), not an exception: the run must start its loop and
        stop the arm through the core, as it would have had the first tick failed."""
        if self.state is DriverState.ACTIVE:
            with contextlib.suppress(DriverError):  # _call recorded it: self.fault
                await self._call("before_first_tick", self.driver.before_first_tick())

    async def deactivate(self) -> None:
        self._require(DriverState.ACTIVE, "deactivate")
        await self._call("deactivate", self.driver.deactivate())
        self.state = DriverState.INACTIVE

    async def read(self) -> StateSample:
        """A fresh sample; in FAULT or CLOSED the last good sample, marked with the fault."""
        if self.state in (DriverState.FAULT, DriverState.CLOSED, DriverState.UNCONFIGURED):
            return self._stale_sample()
        sample = await self._call("read", self.driver.read())
        self.last_sample = sample
        return sample

    async def write(self, command: Command) -> Applied:
        """Send ``command`` if ACTIVE and its kind is one the driver declares; otherwise
        refuse it without touching the device."""
        if self.state is not DriverState.ACTIVE:
            return _refused(command.kind, self.fault or ReasonCode.NO_AUTHORITY)
        if command.kind not in self.driver.capabilities:
            return _refused(command.kind, ReasonCode.CONTROLLER_MODE_MISMATCH)
        return await self._call("write", self.driver.write(command))

    async def hold(self) -> Applied:
        """Ask the device to hold; allowed in ACTIVE and INACTIVE (a hold moves nothing)."""
        if self.state not in (DriverState.ACTIVE, DriverState.INACTIVE):
            return _refused(CommandKind.HOLD, self.fault or ReasonCode.NO_AUTHORITY)
        return await self._call("hold", self.driver.hold())

    async def aclose(self) -> None:
        """Deactivate if needed and release everything. Safe to call twice."""
        if self.state is DriverState.CLOSED:
            return
        try:
            if self.state is DriverState.ACTIVE:
                await self._call("deactivate", self.driver.deactivate())
        except DriverError:
            pass  # already recorded as FAULT; closing goes on regardless
        finally:
            started = time.monotonic_ns()
            try:
                await self.driver.aclose()
            finally:
                self._stats("aclose").record(time.monotonic_ns() - started, True)
                self.state = DriverState.CLOSED

    def mark_fault(self, reason: ReasonCode, detail: str) -> None:
        """Record a fault found outside a call (a watchdog, a status word)."""
        if self.state is not DriverState.CLOSED:
            self.state = DriverState.FAULT
            self.fault, self.fault_detail = reason, detail

    async def _call(self, name: str, awaitable: Awaitable[T]) -> T:
        started = time.monotonic_ns()
        try:
            result = await awaitable
        except DriverError as error:
            self._stats(name).record(time.monotonic_ns() - started, False)
            self.mark_fault(error.reason, str(error))
            raise
        except Exception as error:
            self._stats(name).record(time.monotonic_ns() - started, False)
            self.mark_fault(ReasonCode.CONTROLLER_FAULT, f"{type(error).__name__}: {error}")
            raise DriverError(self.name, f"{name} failed: {error}") from error
        finished = time.monotonic_ns()
        self._stats(name).record(finished - started, True)
        self.last_ok_ns = finished
        return result

    def _stats(self, name: str) -> CallStats:
        return self.stats.setdefault(name, CallStats())

    def _require(self, state: DriverState, call: str) -> None:
        if self.state is not state:
            raise LifecycleError(f"{self.name}: {call} needs {state}, driver is {self.state}")

    def _stale_sample(self) -> StateSample:
        faults = (self.fault,) if self.fault else ()
        if self.last_sample is None:
            return StateSample(seq=-1, t_mono_ns=0, source=self.name, q=(), faults=faults)
        return msgspec.structs.replace(self.last_sample, faults=faults)


def _refused(kind: CommandKind, reason: ReasonCode) -> Applied:
    return Applied(kind=kind, t_mono_ns=time.monotonic_ns(), accepted=False, reason=reason)


DriverFactory = Callable[..., Driver]
