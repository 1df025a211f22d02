"""Start an emulator as a child process and wait until it says it is ready.

The child prints one line ``READY {json}`` on stdout once its ports listen; the JSON carries
what the parent needs (ports, pty path). Anything else the child prints goes to its log.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

from stubs.child import PARENT_PID


@contextlib.contextmanager
def children_at_ordinary_priority() -> Iterator[None]:
    """A child inherits the starting thread's scheduling policy: started from warden's control
    loop thread it would run at the loop's SCHED_FIFO priority and take the CPU from the loop.
    ``SCHED_RESET_ON_FORK`` while spawning gives it SCHED_OTHER. (warden's own spawns use
    kernel/shell/realtime.py; the stand-ins' packages import nothing from kernel.)"""
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


class EmulatorStartError(RuntimeError):
    """The emulator exited, or never said READY; its own message went to stderr."""


class EmulatorProcess:
    def __init__(self, module: str, *args: str, ready_timeout_s: float = 20.0) -> None:
        self.command = [sys.executable, "-m", "stubs.child", module, *args]
        """Through :mod:`stubs.child`: it dies with its parent, and is started with vfork."""
        self.ready_timeout_s = ready_timeout_s
        self.info: dict[str, Any] = {}
        self._proc: subprocess.Popen[bytes] | None = None

    def __enter__(self) -> EmulatorProcess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> EmulatorProcess:
        with children_at_ordinary_priority():  # never at the control loop's SCHED_FIFO
            self._proc = subprocess.Popen(
                self.command, stdout=subprocess.PIPE, stderr=None, start_new_session=True,
                env={**os.environ, "PYTHONUNBUFFERED": "1", PARENT_PID: str(os.getpid())},
            )
        self.info = self._wait_ready()
        return self

    @property
    def pid(self) -> int:
        return self._proc.pid if self._proc else -1

    def alive(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def stop(self, timeout_s: float = 5.0) -> None:
        if self._proc is None:
            return
        if self._proc.poll() is None:
            os.killpg(self._proc.pid, signal.SIGTERM)
            with contextlib.suppress(ProcessLookupError):  # a stopped child acts on it only now
                os.killpg(self._proc.pid, signal.SIGCONT)
            try:
                self._proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self._proc.pid, signal.SIGKILL)
                self._proc.wait()
        if self._proc.stdout:
            self._proc.stdout.close()
        self._proc = None

    def _wait_ready(self) -> dict[str, Any]:
        stdout = self._proc.stdout if self._proc else None
        if stdout is None:
            raise RuntimeError("emulator has no stdout")
        deadline = time.monotonic() + self.ready_timeout_s
        while time.monotonic() < deadline:
            ready, _, _ = select.select([stdout], [], [], 0.1)
            if ready:
                line = stdout.readline()
                if not line:
                    break
                if line.startswith(b"READY"):
                    return json.loads(line[5:] or b"{}")
            elif self._proc and self._proc.poll() is not None:
                break
        code = self._proc.poll() if self._proc else None
        self.stop()
        raise EmulatorStartError(f"emulator {' '.join(self.command)} not ready (exit code "
                                 f"{code})")
