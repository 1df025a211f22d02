"""``warden run --log-format json``: every line on stderr is a JSON log line (progress included),
and a loop that runs without real-time scheduling says so as a warning, each remedy whole.

One wall-clock run of the simulated cell as a process an unprivileged systemd unit would be:
CAP_SYS_NICE and CAP_IPC_LOCK dropped, RLIMIT_RTPRIO 0 and a 64 KiB RLIMIT_MEMLOCK, so both
SCHED_FIFO and mlockall are refused whoever runs the test.
"""

from __future__ import annotations

import ctypes
import json
import os
import resource
import subprocess
import sys
from typing import Any

import pytest

from tests.cell.harness import MANIFESTS

pytestmark = pytest.mark.slow

ROOT = MANIFESTS.parent
_PR_CAPBSET_DROP = 24
_CAP_IPC_LOCK, _CAP_SYS_NICE = 14, 23


def _as_an_unprivileged_unit() -> None:
    """In the child before exec: what a unit without LimitRTPRIO, LimitMEMLOCK and the two
    capabilities gives warden."""
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (_CAP_SYS_NICE, _CAP_IPC_LOCK):
        if libc.prctl(_PR_CAPBSET_DROP, cap, 0, 0, 0) != 0 and os.geteuid() == 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP)")
    resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))
    resource.setrlimit(resource.RLIMIT_MEMLOCK, (64 << 10, 64 << 10))


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[subprocess.CompletedProcess[str],
                                                           list[dict[str, Any]]]:
    tmp = tmp_path_factory.mktemp("logs")
    done = subprocess.run(
        [sys.executable, "-m", "kernel.cli", "run", "--cycles", "1", "--log-format", "json",
         "--json", "-", "--journal-dir", str(tmp / "runs")], cwd=ROOT, capture_output=True,
        text=True, timeout=300, check=False, preexec_fn=_as_an_unprivileged_unit)
    # 1: the cycle not verified. Without SCHED_FIFO on a loaded machine that can happen; what
    # is tested here is what the run says, not how well it ran.
    assert done.returncode in (0, 1), done.stderr[-3000:]
    return done, [json.loads(line) for line in done.stderr.splitlines() if line.startswith("{")]


def _events(lines: list[dict[str, Any]], name: str) -> list[dict[str, Any]]:
    return [line for line in lines if line.get("event") == name]


def test_progress_is_structured_log_lines(run) -> None:  # type: ignore[no-untyped-def]
    done, lines = run
    for number, line in enumerate(done.stderr.splitlines(), start=1):
        try:
            json.loads(line)
        except json.JSONDecodeError:
            pytest.fail(f"stderr line {number} is not a JSON log line: {line!r}")
    steps = [line["step"] for line in _events(lines, "progress")]
    assert steps[0] == "start" and "transport" in steps
    assert {(line["cycle"], line["of"]) for line in _events(lines, "progress")} == {(1, 1)}
    # The summary is stdout's JSON; stderr has no table. Each finished cycle is a log line.
    summary = json.loads(done.stdout)
    assert [(line["cycle"], line["verified"]) for line in _events(lines, "cycle done")] == [
        (cycle["index"], cycle["verified"]) for cycle in summary["cycles"]["detail"]]


def test_scheduling_refused_is_a_warning_with_every_remedy(run) -> None:  # type: ignore
    _, lines = run
    [line] = _events(lines, "scheduling")
    assert line["level"] == "warning"
    assert line["in_effect"] == "default scheduler, memory not locked"
    fifo, mlock = line["problems"]
    assert fifo == ("SCHED_FIFO not permitted: run as root or grant CAP_SYS_NICE / LimitRTPRIO "
                    "in the systemd unit")
    assert mlock.startswith("mlockall ") and "LimitMEMLOCK" in mlock and "..." not in mlock
