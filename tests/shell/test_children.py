"""Children warden starts run at the ordinary priority and die with warden.

A child inherits the scheduling policy of the thread that starts it: a policy server or a job
worker started from the control loop's SCHED_FIFO thread took the CPU from the loop (a restart
mid-run held it back 105 ms). And a child started without a ``preexec_fn`` (so that
``subprocess`` may vfork a large, memory-locked process) must still die with its parent.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from kernel.shell.realtime import children_at_ordinary_priority

ROOT = Path(__file__).resolve().parents[2]
PRINT_POLICY = "import os; print(os.sched_getscheduler(0))"


def _policy_of_child() -> int:
    done = subprocess.run([sys.executable, "-c", PRINT_POLICY], capture_output=True, text=True,
                          check=True)
    return int(done.stdout)


def _on_a_fifo_thread() -> dict[str, int]:
    """Spawn from a SCHED_FIFO thread, inside and outside the block; what each child got."""
    seen: dict[str, int] = {}

    def body() -> None:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
        seen["outside"] = _policy_of_child()
        with children_at_ordinary_priority():
            seen["inside"] = _policy_of_child()
        seen["caller after"] = os.sched_getscheduler(0)

    thread = threading.Thread(target=body)
    thread.start()
    thread.join()
    return seen


def test_children_started_in_the_block_run_at_the_ordinary_priority() -> None:
    try:
        seen = _on_a_fifo_thread()
    except PermissionError:
        pytest.skip("not exercised: this user may not set SCHED_FIFO")
    if not seen:
        pytest.skip("not exercised: this user may not set SCHED_FIFO")
    assert seen == {"outside": os.SCHED_FIFO, "inside": os.SCHED_OTHER,
                    "caller after": os.SCHED_FIFO}


def test_an_emulator_dies_with_the_process_that_started_it(tmp_path: Path) -> None:
    """A parent (its own process) starts the reference policy server through
    stubs/process.py, prints the child's pid, and is SIGKILLed; the child must go."""
    parent = subprocess.Popen(
        [sys.executable, "-c",
         "import time; from stubs.process import EmulatorProcess\n"
         "p = EmulatorProcess('stubs.policy_server', '--host', '127.0.0.1', '--port', '0')\n"
         "p.start(); print(p.pid, flush=True); time.sleep(60)"],
        cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        line = parent.stdout.readline() if parent.stdout else ""
        child = int(line)
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and _alive(child):
            time.sleep(0.05)
        assert not _alive(child), "the emulator outlived its parent"
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"
