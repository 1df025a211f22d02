"""What the driver tests share: an active driver for the length of a block, a test module run as
a script in a fresh interpreter, and the ground-truth checks of the device-watchdog tests."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

from drivers.base import ControlConfig, Driver
from drivers.lifecycle import ManagedDriver

ROOT = Path(__file__).resolve().parents[2]
REST_RAD_S = 0.01
"""Every joint slower than this (ground truth) counts as at rest."""

GroundTruth = Callable[[], dict[str, Any]]
"""One ``ground_truth`` answer of an emulator's test control port (q, qd, t_ns, ...)."""


@contextlib.asynccontextmanager
async def active(driver: Driver, control: ControlConfig) -> AsyncIterator[ManagedDriver]:
    """``driver`` managed, configured and active; closed on the way out, whatever happened."""
    managed = ManagedDriver(driver)
    try:
        await managed.configure(control)
        await managed.activate()
        yield managed
    finally:
        await managed.aclose()


def _child_environment() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def run_script(script: str, *args: object, timeout_s: float) -> subprocess.CompletedProcess[str]:
    """Run ``script`` (a test module's own ``__main__``) in a child interpreter, so that a vendor
    library crashing there fails the test instead of taking pytest with it."""
    return subprocess.run(
        [sys.executable, script, *map(str, args)], capture_output=True, text=True,
        timeout=timeout_s, cwd=ROOT, env=_child_environment(),
    )


def start_script(script: str, *args: object) -> subprocess.Popen[str]:
    """``script`` in a child interpreter that the test controls (and may kill); its stdout is a
    pipe of text lines, its stderr goes to the test's."""
    return subprocess.Popen([sys.executable, script, *map(str, args)], stdout=subprocess.PIPE,
                            text=True, cwd=ROOT, env=_child_environment())


def wait_for_line(child: subprocess.Popen[str], prefix: str) -> str:
    """The first line the child prints that starts with ``prefix`` (the child must print it or
    exit: a child that exits first fails the test with its exit code)."""
    assert child.stdout is not None
    for line in child.stdout:
        if line.startswith(prefix):
            return line
    raise AssertionError(f"child exited with {child.wait()} before printing {prefix!r}")


def wait_until_moving(truth: GroundTruth, child: subprocess.Popen[str], joint: int,
                      min_rad_s: float, timeout_s: float) -> dict[str, Any]:
    """Poll the ground truth until ``joint`` moves faster than ``min_rad_s`` while ``child``
    (the process commanding it) runs."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if child.poll() is not None:
            raise AssertionError(f"the streaming child exited with {child.returncode} (its "
                                 "stderr is in the captured output)")
        sample = truth()
        if abs(sample["qd"][joint]) > min_rad_s:
            return sample
        time.sleep(0.002)
    raise AssertionError(f"joint {joint} never moved faster than {min_rad_s} rad/s "
                         f"within {timeout_s} s")


def seconds_to_standstill(truth: GroundTruth, since: float, timeout_s: float,
                          settled_samples: int = 5) -> tuple[float, dict[str, Any]]:
    """Wall time from ``since`` (time.monotonic) to the first of ``settled_samples`` ground-truth
    samples in a row with every joint at rest, and that sample; AssertionError after
    ``timeout_s`` without it."""
    first_at_rest: tuple[float, dict[str, Any]] | None = None
    in_a_row = 0
    while time.monotonic() - since < timeout_s:
        sample, at = truth(), time.monotonic()
        if max(abs(v) for v in sample["qd"]) < REST_RAD_S:
            first_at_rest = first_at_rest or (at - since, sample)
            in_a_row += 1
            if in_a_row == settled_samples:
                return first_at_rest
        else:
            first_at_rest, in_a_row = None, 0
        time.sleep(0.002)
    raise AssertionError(f"the arm was still moving {timeout_s} s later: {truth()['qd']}")
