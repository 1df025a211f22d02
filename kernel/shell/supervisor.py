"""Task supervision on exactly one asyncio.TaskGroup, with trio's "started" handshake.

Every child runs inside the group (no detached tasks). A child receives a ``started`` callable
and ``Supervisor.start`` returns only once it was called, so the kernel knows the control loop
or a driver is ready before it starts what depends on it. Every failure of a child (any
exception but CancelledError) goes to ``on_failure(name, exception)``: the owner turns it into a
fallback trigger, so nothing dies silently. A critical failure then stops the siblings in
reverse start order and surfaces as an ExceptionGroup from ``async with``; a non-critical child
is restarted with bounded exponential backoff, or left stopped.

Stopping is ordered and shielded: children are cancelled one at a time, newest first, and each
is awaited until its ``finally`` (a driver ``hold()``) has run, even if the caller is cancelled
meanwhile; the caller's cancellation is re-raised afterwards, never swallowed.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass
from enum import StrEnum
from types import TracebackType
from typing import Any, Protocol, Self

import structlog

_log = structlog.get_logger("kernel.shell.supervisor")


class Started(Protocol):
    def __call__(self, value: Any = None) -> None: ...


ChildFn = Callable[[Started], Awaitable[None]]
FailureHook = Callable[[str, BaseException], None]


class StartError(RuntimeError):
    """A child failed, returned or timed out before calling ``started()``."""


class ChildState(StrEnum):
    STARTING = "starting"
    RUNNING = "running"
    BACKOFF = "backoff"
    FINISHED = "finished"
    STOPPED = "stopped"  # failed and not restarted (non-critical), or cancelled
    FAILED = "failed"  # a critical failure


@dataclass(frozen=True, slots=True)
class RestartPolicy:
    """Restarts for a non-critical child: at most ``max_restarts``, backoff doubling to a cap."""

    max_restarts: int = 0
    initial_backoff_s: float = 0.05
    max_backoff_s: float = 2.0
    multiplier: float = 2.0

    def backoff_s(self, attempt: int) -> float:
        return min(self.max_backoff_s, self.initial_backoff_s * self.multiplier ** attempt)


@dataclass(frozen=True, slots=True)
class ChildStatus:
    name: str
    critical: bool
    state: ChildState
    restarts: int
    last_failure: str | None  # exception type name only: bounded


class _Child:
    def __init__(self, name: str, fn: ChildFn, critical: bool, policy: RestartPolicy,
                 ready: asyncio.Future[Any]) -> None:
        self.name, self.fn, self.critical, self.policy = name, fn, critical, policy
        self.ready = ready
        self.state = ChildState.STARTING
        self.restarts = 0
        self.last_failure: str | None = None
        self.task: asyncio.Task[None] | None = None

    def started(self, value: Any = None) -> None:
        if not self.ready.done():
            self.ready.set_result(value)
        self.state = ChildState.RUNNING

    def status(self) -> ChildStatus:
        return ChildStatus(self.name, self.critical, self.state, self.restarts, self.last_failure)


MAX_DESCRIBED = 4
"""Sub-exceptions of a group named in a failure's description (the rest are counted)."""
MAX_MESSAGE = 160


def describe(exc: BaseException) -> str:
    """``Type: message`` of a failure, bounded; an exception group names its first few
    sub-exceptions (nested groups flattened) instead of only saying "ExceptionGroup".

    A log line stays bounded (docs: kernel/shell/logging.py), so each message is cut at
    :data:`MAX_MESSAGE` characters.
    """
    if not isinstance(exc, BaseExceptionGroup):
        return _one(exc)
    leaves = list(_leaves(exc))
    named = "; ".join(_one(leaf) for leaf in leaves[:MAX_DESCRIBED])
    more = f"; and {len(leaves) - MAX_DESCRIBED} more" if len(leaves) > MAX_DESCRIBED else ""
    return f"{type(exc).__name__} of {len(leaves)}: {named}{more}"


def failure_fields(exc: BaseException) -> dict[str, object]:
    """Log fields for a failure: its type and message, and an exception group's sub-exceptions
    as a list (each one a bounded log value of its own)."""
    fields: dict[str, object] = {"error": type(exc).__name__, "detail": _one(exc)}
    if isinstance(exc, BaseExceptionGroup):
        fields["sub_errors"] = [_one(leaf) for leaf in list(_leaves(exc))[:MAX_DESCRIBED]]
    return fields


def _one(exc: BaseException) -> str:
    message = str(exc)
    if len(message) > MAX_MESSAGE:
        message = f"{message[:MAX_MESSAGE]}..."
    return f"{type(exc).__name__}: {message}" if message else type(exc).__name__


def _leaves(group: BaseExceptionGroup) -> Iterator[BaseException]:
    for exc in group.exceptions:
        if isinstance(exc, BaseExceptionGroup):
            yield from _leaves(exc)
        else:
            yield exc


def _log_failure(name: str, exc: BaseException) -> None:
    _log.error("child_failed", child=name, **failure_fields(exc))


class Supervisor:
    """One TaskGroup of supervised children.

    ``async with Supervisor(on_failure=hook) as sup: await sup.start("loop", fn, critical=True)``

    Leaving the block normally waits for the children (TaskGroup semantics): call
    :meth:`shutdown` to stop long-running ones. Leaving it with an exception stops them in
    reverse start order first. ``on_failure`` must not raise; if it does, that exception fails
    the group, loudly. ``start`` must be awaited from the block or from a child.
    """

    def __init__(self, *, on_failure: FailureHook = _log_failure,
                 restart: RestartPolicy = RestartPolicy(),
                 start_timeout_s: float | None = 10.0) -> None:
        self._on_failure = on_failure
        self._restart = restart
        self._start_timeout_s = start_timeout_s
        self._group = asyncio.TaskGroup()
        self._children: list[_Child] = []

    async def __aenter__(self) -> Self:
        await self._group.__aenter__()
        return self

    async def __aexit__(self, et: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> bool | None:
        deferred = await self._stop_in_reverse() if et is not None else None
        suppressed = await self._group.__aexit__(et, exc, tb)
        if deferred is not None:
            raise deferred
        return suppressed

    async def start(self, name: str, coro_fn: ChildFn, *, critical: bool,
                    restart: RestartPolicy | None = None) -> Any:
        """Run ``coro_fn(started)`` in the group; return the value it passes to ``started()``.

        Raises:
            StartError: the child failed, returned or did not call ``started()`` in time.
        """
        policy = restart if restart is not None else self._restart
        child = _Child(name, coro_fn, critical, policy, asyncio.get_running_loop().create_future())
        self._children.append(child)
        child.task = self._group.create_task(self._supervise(child), name=name)
        try:
            async with asyncio.timeout(self._start_timeout_s):
                return await child.ready
        except TimeoutError as exc:
            child.task.cancel()
            self._report(child, exc)
            raise StartError(f"{name} did not call started() within {self._start_timeout_s} s") \
                from exc
        except asyncio.CancelledError:
            child.task.cancel()  # like trio: a child not yet started shares the caller's fate
            raise

    async def shutdown(self) -> None:
        """Cancel every child, newest first, each run to the end of its ``finally``."""
        deferred = await self._stop_in_reverse()
        if deferred is not None:
            raise deferred

    def children(self) -> tuple[ChildStatus, ...]:
        return tuple(child.status() for child in self._children)

    # -- internals -----------------------------------------------------------------------------
    async def _supervise(self, child: _Child) -> None:
        try:
            while await self._run_once(child):
                child.state = ChildState.BACKOFF
                await asyncio.sleep(child.policy.backoff_s(child.restarts))
                child.restarts += 1
        except asyncio.CancelledError:
            child.state = ChildState.STOPPED
            raise

    async def _run_once(self, child: _Child) -> bool:
        """Run the child once; True if it failed and is to be restarted."""
        child.state = ChildState.STARTING  # started() moves it to RUNNING
        try:
            await child.fn(child.started)
            if not child.ready.done():
                raise StartError(f"{child.name} returned without calling started()")
        except Exception as exc:  # every failure is reported, then handled below
            self._report(child, exc)
            return await self._after_failure(child, exc)
        child.state = ChildState.FINISHED
        return False

    async def _after_failure(self, child: _Child, exc: Exception) -> bool:
        """Decide what follows a failure: True to restart; raises for a critical child."""
        if child.critical:
            child.state = ChildState.FAILED
            # Stop the siblings in order before the TaskGroup aborts them in no order. A
            # cancellation arriving meanwhile is dropped on purpose: this task ends with
            # ``exc``, which is what the group must surface.
            await self._stop_in_reverse(exclude=child)
            raise exc
        if not child.ready.done():
            error = StartError(f"{child.name} failed before started()")
            error.__cause__ = exc
            child.ready.set_exception(error)
            child.state = ChildState.STOPPED
            return False
        if child.restarts >= child.policy.max_restarts:
            child.state = ChildState.STOPPED
            return False
        return True

    def _report(self, child: _Child, exc: BaseException) -> None:
        child.last_failure = type(exc).__name__
        self._on_failure(child.name, exc)

    async def _stop_in_reverse(self, exclude: _Child | None = None
                               ) -> asyncio.CancelledError | None:
        """Cancel and await children newest first; return a cancellation of the caller, if any."""
        deferred: asyncio.CancelledError | None = None
        current = asyncio.current_task()
        for child in reversed(self._children):
            task = child.task
            if child is exclude or task is None or task is current or task.done():
                continue
            task.cancel()
            while not task.done():
                try:
                    await asyncio.wait((task,))
                except asyncio.CancelledError as exc:
                    deferred = exc  # finish the ordered stop first; the caller re-raises it
        return deferred
