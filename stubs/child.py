"""Run a module as a child that dies with its parent: ``python -m stubs.child MODULE ARGS...``.

The parent (warden, or a test) starts emulators and the reference policy server through this
runner rather than with a ``preexec_fn``: a ``preexec_fn`` forces ``subprocess`` to ``fork()``
instead of ``vfork()``, and forking warden's process (hundreds of MB, memory locked for the
control loop) copies its page tables while the loop thread waits; a policy server restarted
mid-run stalled the 500 Hz loop for about 100 ms that way. So the child asks the kernel itself,
first thing, for SIGTERM when its parent dies (``PR_SET_PDEATHSIG``), then checks that the
parent named in ``WARDEN_PARENT_PID`` is still its parent (it may have died before the
request), then runs ``MODULE`` as ``__main__`` with ``ARGS`` as its command line.
"""

from __future__ import annotations

import ctypes
import os
import runpy
import signal
import sys

PARENT_PID = "WARDEN_PARENT_PID"
_PR_SET_PDEATHSIG = 1


def die_with_parent() -> None:
    """SIGTERM to this process when its parent dies; exit at once if it already has."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    expected = os.environ.get(PARENT_PID)
    if expected is not None and expected.isdigit() and os.getppid() != int(expected):
        sys.exit(f"{sys.argv[0]}: the parent {expected} is gone")


def wait_for_stop_signal() -> None:
    """Block the main thread until SIGTERM or SIGINT arrives.

    The handlers do nothing: the kernel-side write to the wakeup pipe (``set_wakeup_fd``) ends
    the read, even for a signal that came before it. (A handler calling
    ``threading.Event.set()`` while the main thread sat in that Event's ``wait()`` could wait
    for the Event's own lock forever: kernel/safety/service.py's monitor hung so.)"""
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    previous_fd = signal.set_wakeup_fd(write_fd)
    previous = {signum: signal.signal(signum, lambda *_: None)
                for signum in (signal.SIGTERM, signal.SIGINT)}
    try:
        os.read(read_fd, 1)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        signal.set_wakeup_fd(previous_fd)
        os.close(read_fd)
        os.close(write_fd)


def main() -> None:
    if len(sys.argv) < 2:
        sys.exit("usage: python -m stubs.child MODULE [ARGS...]")
    die_with_parent()
    module, sys.argv = sys.argv[1], [sys.argv[1], *sys.argv[2:]]
    runpy.run_module(module, run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main()
