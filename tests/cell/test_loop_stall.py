"""A stalled control loop on the wall clock: measured, reported and a fault (issue 15, item 4).

The simulated cell runs live; a tick hook blocks the loop's thread once (a test-only stand-in
for a blocking call or a stopped process). Tick lateness is measured from the latest deadline
and cannot show the stall; the longest gap between ticks and the periods skipped must, in the
summary, summary.json, the journal and the log, and since the stall outlasts the cell's state
watchdog (50 ms) the core must have made it a WATCHDOG fault, which the replay reproduces.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest
from rich.console import Console
from structlog.testing import capture_logs

from kernel.app.live import run_live
from kernel.app.report import render_summary
from kernel.app.session import RunContext
from kernel.shell.loop import run
from tests.cell.harness import manifest, replays_identically, run_dir

pytestmark = pytest.mark.slow

STALL_S = 0.3
PERIOD_S = 0.002


class _StallOnce:
    """Blocks the loop for ``STALL_S`` after ``at`` ticks, ends the run ``after`` ticks later."""

    def __init__(self, at: int = 300, after: int = 100) -> None:
        self.at, self.after = at, after
        self.ticks = 0

    def __call__(self, context: RunContext) -> bool:
        self.ticks += 1
        if self.ticks == self.at:
            time.sleep(STALL_S)  # the loop's thread stands still: no tick, no command
        return self.ticks >= self.at + self.after


def test_a_stall_is_reported_and_is_a_watchdog_fault(tmp_path: Path) -> None:
    with capture_logs() as logs:
        summary = run(run_live(manifest("sim-ur5e.toml", cycles=1), tmp_path, hook=_StallOnce()))
    stalled_periods = int(STALL_S / PERIOD_S) - 2  # the sleep, less a period's slack each side

    loop = summary["loop"]
    assert loop["longest_gap_ms"] >= STALL_S * 1000
    assert loop["periods_skipped"] >= stalled_periods
    assert loop["lateness_us"]["max"] < PERIOD_S * 1e6  # what hid the stall before
    console = Console(record=True, width=120)
    render_summary(summary, console)
    table = console.export_text()
    assert re.search(rf"longest tick gap \(ms\) +│ {loop['longest_gap_ms']:.1f} ", table)
    assert re.search(rf"periods skipped +│ {loop['periods_skipped']} ", table)
    written = json.loads((run_dir(tmp_path) / "summary.json").read_text())
    assert written["loop"]["longest_gap_ms"] == loop["longest_gap_ms"]
    assert written["loop"]["periods_skipped"] == loop["periods_skipped"]

    stalls = [e for e in logs if e["event"] == "control loop stalled"]
    assert len(stalls) == 1 and stalls[0]["gap_ms"] >= STALL_S * 1000
    assert stalls[0]["periods_skipped"] >= stalled_periods
    (closing,) = [e for e in logs if e["event"] == "control loop"]
    assert closing["longest_gap_ms"] == loop["longest_gap_ms"]

    journal = [json.loads(line) for line in (run_dir(tmp_path) / "journal.jsonl").open()]
    skipped = [e for e in journal if e.get("kind") == "tick" and e.get("skipped", 0) > 0]
    assert max(e["skipped"] for e in skipped) >= stalled_periods

    watchdog = [t for t in summary["fallback_transitions"] if t["trigger"] == "WATCHDOG"]
    assert watchdog and watchdog[0]["to"] == "CONTROLLER_STOP"
    decisions = [json.loads(line) for line in (run_dir(tmp_path) / "decisions.jsonl").open()]
    (fault,) = [d for d in decisions if d["kind"] == "transition" and d["trigger"] == "WATCHDOG"]
    assert "no control tick for" in fault["detail"]
    assert replays_identically(run_dir(tmp_path))
