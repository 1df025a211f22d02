"""What the driver tests share: an active driver for the length of a block, and a test module
run as a script in a fresh interpreter."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import AsyncIterator
from pathlib import Path

from drivers.base import ControlConfig, Driver
from drivers.lifecycle import ManagedDriver

ROOT = Path(__file__).resolve().parents[2]


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


def run_script(script: str, *args: object, timeout_s: float) -> subprocess.CompletedProcess[str]:
    """Run ``script`` (a test module's own ``__main__``) in a child interpreter, so that a vendor
    library crashing there fails the test instead of taking pytest with it."""
    return subprocess.run(
        [sys.executable, script, *map(str, args)], capture_output=True, text=True,
        timeout=timeout_s, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
