"""Best-effort real-time settings for the loop thread: SCHED_FIFO, mlockall, CPU affinity.

Each setting is optional and none of them raises: :func:`try_realtime` returns a
:class:`RealtimeReport` saying what took effect and, for what did not, one human sentence each,
which :func:`log_report` logs whole, as a warning. The timing notes (bench/loop.py measures it)
show SCHED_FIFO on the loop thread is what takes the 500 Hz tail from ~1 ms to a few hundred
microseconds, so a deployment that silently runs without it must at least say so.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

MCL_CURRENT = 1
MCL_FUTURE = 2

_FIFO_DENIED = "not permitted: run as root or grant CAP_SYS_NICE / LimitRTPRIO in the systemd unit"
_MLOCK_DENIED = ("not permitted: run as root or grant CAP_IPC_LOCK / raise LimitMEMLOCK in the "
                 "systemd unit")


@dataclass(frozen=True, slots=True)
class RealtimeReport:
    """What :func:`try_realtime` achieved, plus what is needed to undo it."""

    fifo: bool
    priority: int | None
    mlocked: bool
    cpus: frozenset[int] | None
    problems: tuple[str, ...]
    previous_policy: int
    previous_priority: int

    @property
    def ok(self) -> bool:
        return not self.problems

    def in_effect(self) -> str:
        """What took effect: ``SCHED_FIFO priority 50, memory locked``."""
        sched = f"SCHED_FIFO priority {self.priority}" if self.fifo else "default scheduler"
        parts = [sched, "memory locked" if self.mlocked else "memory not locked"]
        if self.cpus is not None:
            parts.append(f"cpus {sorted(self.cpus)}")
        return ", ".join(parts)

    def summary(self) -> str:
        """One line for a summary table: what is in effect, then each problem."""
        return "; ".join((self.in_effect(), *self.problems))


def log_report(logger: Any, report: RealtimeReport, event: str = "scheduling") -> None:
    """Log ``report`` as one line: a warning when something did not take effect, each problem
    a field of its own, whole.

    A log line caps each string field (kernel/shell/logging.py); the joined summary of two
    refusals runs past that cap and lost its last remedy (LimitMEMLOCK). Each problem alone is
    one short sentence, well inside it.
    """
    emit = logger.info if report.ok else logger.warning
    emit(event, in_effect=report.in_effect(), problems=list(report.problems))


def try_realtime(priority: int = 50, *, fifo: bool = True, lock_memory: bool = True,
                 cpus: Iterable[int] | None = None) -> RealtimeReport:
    """Try SCHED_FIFO at ``priority`` for the calling thread, ``mlockall`` and CPU pinning.

    Linux applies ``sched_setscheduler(0, ...)`` and ``sched_setaffinity(0, ...)`` to the calling
    thread only, so call this from the event loop's thread. Never raises.
    """
    previous_policy = os.sched_getscheduler(0)
    previous_priority = os.sched_getparam(0).sched_priority
    problems: list[str] = []
    got_fifo = fifo and _collect(problems, "SCHED_FIFO", _set_fifo, priority)
    mlocked = lock_memory and _collect(problems, "mlockall", _mlockall)
    pinned = cpus is not None and _collect(problems, "cpu affinity", _pin, frozenset(cpus))
    return RealtimeReport(
        fifo=got_fifo, priority=priority if got_fifo else None, mlocked=mlocked,
        cpus=frozenset(os.sched_getaffinity(0)) if pinned else None, problems=tuple(problems),
        previous_policy=previous_policy, previous_priority=previous_priority)


def restore(report: RealtimeReport) -> None:
    """Undo :func:`try_realtime` (scheduler and memory lock) on the calling thread."""
    if report.fifo:
        param = os.sched_param(report.previous_priority)
        os.sched_setscheduler(0, report.previous_policy, param)
    if report.mlocked:
        _libc().munlockall()


def current_policy() -> str:
    """The calling thread's scheduling policy as a name, e.g. ``"SCHED_FIFO"``."""
    policy = os.sched_getscheduler(0)
    names = {os.SCHED_OTHER: "SCHED_OTHER", os.SCHED_FIFO: "SCHED_FIFO", os.SCHED_RR: "SCHED_RR",
             os.SCHED_BATCH: "SCHED_BATCH", os.SCHED_IDLE: "SCHED_IDLE"}
    return names.get(policy, str(policy))


def _collect(problems: list[str], what: str, action: Callable[..., str | None],
             *args: object) -> bool:
    message = action(*args)
    if message is not None:
        problems.append(f"{what} {message}")
    return message is None


@contextlib.contextmanager
def children_at_ordinary_priority() -> Iterator[None]:
    """Processes started inside this block run at the ordinary priority.

    A child inherits the scheduling policy of the thread that starts it: started from the
    control loop's thread (or a thread it made), a policy server or a job worker would run at
    the loop's SCHED_FIFO priority and take the CPU from the loop itself (a reference server
    restarted mid-run held the 500 Hz loop back 105 ms while it imported its modules).
    ``SCHED_RESET_ON_FORK`` on the calling thread, only while it spawns, gives its children
    SCHED_OTHER and leaves its own priority as it is.
    """
    policy = os.sched_getscheduler(0)
    if policy not in (os.SCHED_FIFO, os.SCHED_RR):
        yield
        return
    param = os.sched_getparam(0)
    os.sched_setscheduler(0, policy | os.SCHED_RESET_ON_FORK, param)
    try:
        yield
    finally:
        os.sched_setscheduler(0, policy, param)


def _explain(err: int, denied: str) -> str:
    if err == errno.EPERM:
        return denied
    if err == errno.EINVAL:
        return "rejected: invalid argument (priority out of range, or no such cpu)"
    if err == errno.ENOMEM:
        return "failed: memory lock limit too low (raise LimitMEMLOCK, or grant CAP_IPC_LOCK)"
    return f"failed: {os.strerror(err)}"


def _set_fifo(priority: int) -> str | None:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        return _explain(exc.errno or 0, _FIFO_DENIED)
    return None


def _mlockall() -> str | None:
    if _libc().mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
        return _explain(ctypes.get_errno(), _MLOCK_DENIED)
    return None


def _pin(cpus: frozenset[int]) -> str | None:
    try:
        os.sched_setaffinity(0, cpus)
    except OSError as exc:
        return _explain(exc.errno or 0, "not permitted")
    except (ValueError, OverflowError) as exc:  # a negative or huge cpu number
        return f"rejected: {type(exc).__name__}"
    return None


def _libc() -> ctypes.CDLL:
    return ctypes.CDLL(None, use_errno=True)


def thread_at_ordinary_priority() -> None:
    """The calling thread runs with the ordinary policy, whatever the thread that created it
    had (Linux gives a new thread its creator's, and the control loop's is SCHED_FIFO): disk
    writes and camera reads never compete with the loop."""
    if os.sched_getscheduler(0) != os.SCHED_OTHER:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
