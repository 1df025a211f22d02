"""try_realtime: a well-formed report whether or not SCHED_FIFO is permitted.

The real attempt runs in a subprocess so this test process never runs at SCHED_FIFO or with
its memory locked; the refusal paths are exercised in-process with the system calls faked.
"""

from __future__ import annotations

import ctypes
import errno
import json
import os
import resource
import subprocess
import sys

import pytest

from kernel.shell import realtime
from kernel.shell.realtime import RealtimeReport, current_policy, try_realtime

_PR_CAPBSET_DROP = 24
_CAP_IPC_LOCK = 14
_CAP_SYS_NICE = 23

_CHILD = """
import json
from kernel.shell.realtime import current_policy, restore, try_realtime
report = try_realtime(priority=1)
during = current_policy()
restore(report)
print(json.dumps({"fifo": report.fifo, "priority": report.priority, "mlocked": report.mlocked,
                  "problems": list(report.problems), "summary": report.summary(),
                  "during": during, "after": current_policy()}))
"""


def _drop_rt_capabilities() -> None:
    """In the child before exec: drop CAP_SYS_NICE and CAP_IPC_LOCK, as an unprivileged unit."""
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (_CAP_SYS_NICE, _CAP_IPC_LOCK):
        if libc.prctl(_PR_CAPBSET_DROP, cap, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP)")


def _attempt(unprivileged: bool) -> dict:
    out = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True,
                         check=True, timeout=60, cwd=os.getcwd(),
                         preexec_fn=_drop_rt_capabilities if unprivileged else None)
    return json.loads(out.stdout)


def test_real_attempt_in_a_subprocess_is_well_formed() -> None:
    report = _attempt(unprivileged=False)
    assert report["after"] == "SCHED_OTHER"
    if report["fifo"]:
        assert (report["priority"], report["during"]) == (1, "SCHED_FIFO")
        assert "SCHED_FIFO priority 1" in report["summary"]
    else:
        assert report["priority"] is None and report["during"] == "SCHED_OTHER"
        assert any(p.startswith("SCHED_FIFO ") for p in report["problems"])
    assert report["mlocked"] or any(p.startswith("mlockall ") for p in report["problems"])


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to drop capabilities for the child")
@pytest.mark.skipif(resource.getrlimit(resource.RLIMIT_RTPRIO)[0] > 0,
                    reason="RLIMIT_RTPRIO allows SCHED_FIFO without CAP_SYS_NICE here")
def test_real_refusal_without_capabilities_is_explained() -> None:
    report = _attempt(unprivileged=True)
    assert (report["fifo"], report["during"], report["after"]) == (False, "SCHED_OTHER",
                                                                    "SCHED_OTHER")
    assert report["problems"][0] == ("SCHED_FIFO not permitted: run as root or grant "
                                     "CAP_SYS_NICE / LimitRTPRIO in the systemd unit")
    assert report["mlocked"] or report["problems"][1].startswith("mlockall ")


class _DeniedLibc:
    def mlockall(self, flags: int) -> int:
        return -1


def test_refusals_are_explained_not_raised(monkeypatch: pytest.MonkeyPatch) -> None:
    def denied(*args: object) -> None:
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", denied)
    monkeypatch.setattr(realtime, "_libc", _DeniedLibc)
    monkeypatch.setattr(ctypes, "get_errno", lambda: errno.EPERM)
    report = try_realtime(priority=80)
    assert isinstance(report, RealtimeReport)
    assert (report.fifo, report.priority, report.mlocked, report.ok) == (False, None, False, False)
    summary = report.summary()
    assert "CAP_SYS_NICE / LimitRTPRIO in the systemd unit" in summary
    assert "CAP_IPC_LOCK" in summary
    assert summary.startswith("default scheduler, memory not locked; SCHED_FIFO not permitted")


def test_bad_priority_and_cpus_are_reported(monkeypatch: pytest.MonkeyPatch) -> None:
    def invalid(*args: object) -> None:
        raise OSError(errno.EINVAL, "Invalid argument")

    monkeypatch.setattr(os, "sched_setscheduler", invalid)
    report = try_realtime(priority=500, lock_memory=False, cpus=[-1])
    assert report.problems[0].startswith("SCHED_FIFO rejected: invalid argument")
    assert report.problems[1].startswith("cpu affinity rejected")
    assert report.cpus is None
    report = try_realtime(fifo=False, lock_memory=False, cpus=[10_000])
    assert report.problems == ("cpu affinity rejected: invalid argument "
                               "(priority out of range, or no such cpu)",)


def test_nothing_requested_is_ok_and_leaves_the_process_alone() -> None:
    before = current_policy()
    report = try_realtime(fifo=False, lock_memory=False)
    assert report.ok and not report.fifo and report.summary().startswith("default scheduler")
    assert current_policy() == before == "SCHED_OTHER"
