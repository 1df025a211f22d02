"""What every cell run shares, whichever clock paces it: files, summary, progress, bring-up.

A run directory holds ``journal.jsonl`` (every event the core was fed; ``warden replay`` on it
reproduces every decision) and ``decisions.jsonl`` (the decision log the live run produced),
plus ``summary.json``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from drivers.base import ControlConfig
from kernel.app.compose import Cell, build_cell, effective, world_for
from kernel.app.report import CycleProgress
from kernel.core.config import CoreConfig
from kernel.journal import header
from kernel.manifest import Manifest
from kernel.provenance import provenance
from kernel.shell.heartbeat import HeartbeatStats
from kernel.shell.recorder import Recorder, open_run_files
from kernel.shell.timer import Clock
from kernel.summary import CycleResult, RunSummary, percentiles


@dataclass
class RunFiles:
    directory: Path | None = None
    journal: IO[str] | None = None
    decisions: IO[bytes] | None = None

    def close(self) -> None:
        for stream in (self.journal, self.decisions):
            if stream is not None:
                stream.close()


@dataclass
class RunContext:
    manifest: Manifest
    cell: Cell
    recorder: Recorder
    files: RunFiles
    sections: dict[str, Any]
    """The sections the journal's header carries (what rebuilds this run's core exactly)."""
    summary: RunSummary = field(default_factory=RunSummary)
    lateness_ns: list[int] = field(default_factory=list)
    misses: int = 0
    heartbeat: HeartbeatStats | None = None
    """The safety monitor's heartbeat as sent so far (a live run with ``[safety]``)."""


def open_run(manifest: Manifest, clock: Clock, journal_dir: Path | None,
             progress: CycleProgress | None) -> RunContext:
    """The world, the run's files and the cell; on any failure nothing is left running."""
    world = world_for(manifest)
    try:
        config, sections = effective(manifest, world)
        files = RunFiles()
        if journal_dir is not None:
            files.directory, files.journal, files.decisions = open_run_files(journal_dir,
                                                                             manifest.name)
        head = {**header(sections, manifest.name),
                "provenance": provenance(manifest.digest, manifest.path, manifest.signer)}
        recorder = Recorder(files.journal, files.decisions, head)
        cell = build_cell(manifest, config, world, clock, recorder)
    except BaseException:
        world.close()  # an emulator already started must not outlive a failed build
        raise
    context = RunContext(manifest, cell, recorder, files, sections)
    cell.gateway.listeners.append(context.summary.observe_all)
    cell.controller.on_cycle = _on_cycle(context, progress)
    return context


def _on_cycle(context: RunContext, progress: CycleProgress | None):  # type: ignore[no-untyped-def]
    def record(result: CycleResult) -> None:
        context.summary.cycles.append(result)
        if progress is not None:
            progress.cycle_done(result)
    return record


async def bring_up(context: RunContext) -> None:
    """Connect, configure and activate the driver. The core's motion starts at its first tick
    from the first measured sample: a real device starts wherever it was parked."""
    await context.cell.driver.configure(control_config(context.cell.core.config))
    await context.cell.driver.activate()


def control_config(config: CoreConfig) -> ControlConfig:
    """What the driver is configured with: the arm's joints (not the gripper column), the
    control period and the limits, as the core enforces them."""
    limits = config.limits
    arm = limits.arm_mask
    return ControlConfig(
        dof=int(arm.sum()), period_ns=config.control_period_ns,
        q_lower=tuple(limits.lower[arm].tolist()), q_upper=tuple(limits.upper[arm].tolist()),
        v_max=tuple(limits.velocity[arm].tolist()))


def report_progress(context: RunContext, progress: CycleProgress | None) -> None:
    if progress is None:
        return
    state = context.cell.core.state
    controller = context.cell.controller
    progress.update(min(len(controller.results) + 1, controller.cycles),
                    str(context.cell.controller.runner.step), str(state.task.phase),
                    str(state.fallback.mode))


def finish(context: RunContext, extra: dict[str, Any]) -> dict[str, Any]:
    """The summary as a dict; also written to the run directory."""
    summary = context.summary
    lateness = [n / 1000.0 for n in context.lateness_ns]
    ticks = context.cell.controller.counters.ticks
    summary.loop = {
        "ticks": ticks, "misses": context.misses,
        "miss_rate": context.misses / ticks if ticks else 0.0,
        "lateness_us": _lateness(lateness), **extra.pop("loop", {}),
    }
    summary.extra.update(extra)
    summary.extra["journal"] = {"directory": str(context.files.directory or "-"),
                                "events": context.recorder.stats.events,
                                "gaps": context.recorder.stats.gaps,
                                "error": context.recorder.stats.error}
    summary.extra["driver"] = {"refused_writes": context.cell.controller.counters.refused_writes,
                               "faults": "; ".join(context.cell.controller.counters.driver_faults)
                               or "none"}
    data = summary.as_dict()
    if context.files.directory is not None:
        (context.files.directory / "summary.json").write_text(json.dumps(data, indent=1,
                                                                         default=str))
    return data


def _lateness(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    stats = percentiles(values)
    ordered = sorted(values)
    stats["p99"] = ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]
    stats["p999"] = ordered[min(len(ordered) - 1, int(0.999 * len(ordered)))]
    return stats
