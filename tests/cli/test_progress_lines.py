"""The run's progress as it is shown (kernel/app/report.py), for a cycle a run cut short.

A cycle ended by an interrupt, the run's time or its record has no measured depth
(``CycleResult.depth_m`` is None): the console line says "not measured" and the JSON log line
carries ``depth_mm: null``, rather than the run ending on a TypeError after the arm was held.
"""

from __future__ import annotations

import io
import json

import structlog
from rich.console import Console

from kernel.app.report import CycleProgress
from kernel.summary import CycleResult

CUT = CycleResult(index=2, verified=False, depth_m=None, duration_s=3.2,
                  reason="interrupted by SIGTERM")


def test_a_cut_short_cycle_is_a_json_progress_line_without_a_depth() -> None:
    out = io.StringIO()
    structlog.configure(processors=[structlog.processors.JSONRenderer()],
                        logger_factory=structlog.PrintLoggerFactory(out),
                        cache_logger_on_first_use=False)
    try:
        CycleProgress(3, Console(file=io.StringIO()), structured=True).cycle_done(CUT)
    finally:
        structlog.reset_defaults()
    line = json.loads(out.getvalue())
    assert line["event"] == "cycle done" and line["verified"] is False
    assert line["depth_mm"] is None and line["detail"] == "interrupted by SIGTERM"


def test_a_cut_short_cycle_is_a_console_line_without_a_depth() -> None:
    shown = io.StringIO()
    CycleProgress(3, Console(file=shown, width=200)).cycle_done(CUT)
    assert "cycle 2/3: FAILED (interrupted by SIGTERM)" in shown.getvalue()
