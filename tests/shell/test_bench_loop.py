"""Smoke test of bench/loop.py (in a subprocess: it may switch its thread to SCHED_FIFO)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "bench" / "loop.py"


def test_bench_runs_and_prints_both_variants() -> None:
    out = subprocess.run(
        [sys.executable, str(BENCH), "--seconds", "0.3", "--rounds", "1", "--events", "2000"],
        capture_output=True, text=True, check=True, timeout=120)
    text = out.stdout
    for expected in ("asyncio.sleep", "timerfd + early spin + RT", "p99 ratio naive / timerfd",
                     "targets (timerfd)", "load during timerfd", "RT (SCHED_FIFO + mlockall)"):
        assert expected in text, text
