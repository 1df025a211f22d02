"""What a cell run shows: progress per cycle and phase while it runs, a summary table after.

On a terminal the progress is a live bar per cycle; anywhere else (CI logs, pipes) it is one
plain line per phase change, so logs stay readable; with JSON log lines (``--log-format json``,
the default when stderr is no terminal, e.g. under systemd) it is one structured log line per
phase change, so every line on stderr parses.
"""

from __future__ import annotations

from typing import Any

import structlog
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from kernel.summary import CycleResult

log = structlog.get_logger("warden.run")
STEPS = ("start", "pick approach", "pick descend", "grasp", "lift", "transport", "pre-contact",
         "insert", "verify", "release", "retreat lift", "retreat home", "done")


class CycleProgress:
    def __init__(self, cycles: int, console: Console | None = None, *,
                 structured: bool = False) -> None:
        self.console = console or Console(stderr=True)
        self.cycles = cycles
        self.structured = structured
        self._live = self.console.is_terminal and not structured
        self._progress = Progress(
            TextColumn("[bold]cycle {task.fields[cycle]}/{task.fields[of]}"),
            BarColumn(), TextColumn("{task.fields[step]:<14} {task.fields[mode]}"),
            TimeElapsedColumn(), console=self.console, transient=False,
        ) if self._live else None
        self._task: Any = None
        self._cycle = 0
        self._last = ("", "")

    def __enter__(self) -> CycleProgress:
        if self._progress is not None:
            self._progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._progress is not None:
            self._progress.stop()

    def update(self, cycle: int, step: str, phase: str, mode: str) -> None:
        if cycle != self._cycle:
            self._new_cycle(cycle)
        if (step, mode) == self._last:
            return
        self._last = (step, mode)
        shown = mode if mode != "RUNNING" else phase
        if self._progress is not None:
            done = STEPS.index(step) if step in STEPS else 0
            self._progress.update(self._task, completed=done, step=step, mode=shown)
        elif self.structured:
            log.info("progress", cycle=cycle, of=self.cycles, step=step, mode=shown)
        else:
            self.console.print(f"cycle {cycle}/{self.cycles}  {step:<14} {shown}")

    def cycle_done(self, result: CycleResult) -> None:
        verdict = "verified" if result.verified else f"FAILED ({result.reason})"
        text = (f"cycle {result.index}/{self.cycles}: {verdict}, peg depth "
                f"{_depth(result.depth_m)}, {result.duration_s:.1f} s")
        if self._progress is not None:
            self._progress.update(self._task, completed=len(STEPS) - 1, step="done",
                                  mode="verified" if result.verified else "failed")
            self._progress.console.print(text)
        elif self.structured:
            log.info("cycle done", cycle=result.index, of=self.cycles, verified=result.verified,
                     detail=result.reason or None, depth_mm=None if result.depth_m is None
                     else round(result.depth_m * 1000, 1),
                     duration_s=round(result.duration_s, 1))
        else:
            self.console.print(text)

    def _new_cycle(self, cycle: int) -> None:
        self._cycle = cycle
        if self._progress is not None:
            self._task = self._progress.add_task("cycle", total=len(STEPS) - 1, cycle=cycle,
                                                 of=self.cycles, step="start", mode="")


def render_summary(summary: dict[str, Any], console: Console | None = None) -> None:
    console = console or Console()
    cycles = summary["cycles"]
    table = Table(title=f"warden run: {cycles['verified']}/{cycles['attempted']} cycles verified",
                  show_header=True, header_style="bold")
    table.add_column("measure")
    table.add_column("value", overflow="fold")
    for label, value in _rows(summary):
        table.add_row(label, value)
    console.print(table)


def _rows(s: dict[str, Any]) -> list[tuple[str, str]]:
    rows = [("cycles attempted / verified", f"{s['cycles']['attempted']} / "
             f"{s['cycles']['verified']}")]
    if s.get("trial"):  # why a trial ended, its unfinished cycle counted (kernel/app/trial.py)
        rows.append(("trial", s["trial"]["ended"]))
    for cycle in s["cycles"]["detail"]:
        verdict = "verified" if cycle["verified"] else f"failed: {cycle['reason']}"
        rows.append((f"  cycle {cycle['index']}", f"{verdict}, depth "
                     f"{_depth(cycle['depth_m'])}, {cycle['duration_s']:.1f} s"))
    rows.append(("proposals by phase", _counts(s["proposals_by_phase"])))
    rows.append(("decisions", _counts(s["decisions"])))
    for phase, reasons in s["refusals_by_phase_and_reason"].items():
        rows.append((f"refusals in {phase}", _counts(reasons)))
    rows.append(("projection distance (rad)", _spread(s["projection_distance_rad"], 4)))
    rows.append(("action age (ms)", _spread(s["action_age_ms"], 1)))
    rows.append(("inference round trip (ms)", _spread(s["inference_round_trip_ms"], 1)))
    rows.append(("queue depth (actions)", _spread(s["queue_depth_actions"], 0)))
    rows.append(("inference requests", str(s["inference_requests"])))
    for transition in s["fallback_transitions"]:
        latency = transition.get("latency_ms")
        rows.append((f"fallback at {transition['t'] / 1000:.3f} s",
                     f"{transition['from']} → {transition['to']} ({transition['trigger']})"
                     + (f", command {latency:.1f} ms later" if latency is not None else "")))
    loop = s.get("loop") or {}
    if loop:
        rows.append(("control ticks", str(loop.get("ticks", 0))))
        rows.append(("tick lateness (us)",
                     f"p50 {loop['lateness_us']['p50']:.0f}, p99 {loop['lateness_us']['p99']:.0f},"
                     f" max {loop['lateness_us']['max']:.0f}" if loop.get("lateness_us") else "-"))
        rows.append(("deadline misses", f"{loop.get('misses', 0)} "
                     f"({loop.get('miss_rate', 0.0) * 100:.2f} %)"))
        if "longest_gap_ms" in loop:  # a stall shows here, never in the lateness
            rows.append(("longest tick gap (ms)", f"{loop['longest_gap_ms']:.1f}"))
            rows.append(("periods skipped", str(loop["periods_skipped"])))
        if loop.get("realtime"):
            rows.append(("scheduling", loop["realtime"]))
    for key in ("link", "driver", "journal"):
        if s.get(key):
            rows.append((key, _counts(s[key]) if isinstance(s[key], dict) else str(s[key])))
    return rows


def _depth(depth_m: float | None) -> str:
    return "not measured" if depth_m is None else f"{depth_m * 1000:.1f} mm"


def _counts(counts: dict[str, Any]) -> str:
    return ", ".join(f"{k} {v}" for k, v in counts.items()) or "-"


def _spread(stats: dict[str, Any], digits: int) -> str:
    if not stats.get("n"):
        return "-"
    return (f"p50 {stats['p50']:.{digits}f}, p95 {stats['p95']:.{digits}f}, "
            f"max {stats['max']:.{digits}f} (n={stats['n']})")
