"""What every cell run shares, whichever clock paces it: files, summary, progress, bring-up.

A run directory holds ``journal.jsonl`` (every event the core was fed; ``warden replay`` on it
reproduces every decision) and ``decisions.jsonl`` (the decision log the live run produced),
plus ``summary.json``.
"""

from __future__ import annotations

import contextlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import structlog

from drivers.base import ControlConfig
from kernel.app.compose import Cell, build_cell, effective, world_for
from kernel.app.interrupt import StopSignals
from kernel.app.report import CycleProgress
from kernel.core.config import CoreConfig
from kernel.journal import header
from kernel.manifest import Manifest, ManifestError
from kernel.provenance import provenance
from kernel.sections import ScenarioSections
from kernel.shell.device_lock import note_run_directory
from kernel.shell.heartbeat import HeartbeatStats
from kernel.shell.record_file import RecordFile, open_run_files
from kernel.shell.recorder import Recorder
from kernel.shell.timer import Clock
from kernel.summary import CycleResult, RunSummary, percentiles

log = structlog.get_logger("warden.run")


@dataclass
class RunFiles:
    directory: Path | None = None
    journal: RecordFile | None = None
    decisions: RecordFile | None = None

    @classmethod
    def open(cls, journal_dir: Path | None, name: str) -> RunFiles:
        """A new run directory, or no files at all without a journal directory.

        Raises:
            ManifestError: the directory cannot hold the run's record (``warden run`` checked
                it before; this names the directory if it changed since).
        """
        if journal_dir is None:
            return cls()
        try:
            return cls(*open_run_files(journal_dir, name))
        except OSError as error:
            raise ManifestError(f"{journal_dir}: cannot record the run there: "
                                f"{error.strerror or error}") from error

    def close(self) -> None:
        """Close the files (the recorder closes them at the end of a run; this is for a run
        that failed before it had one)."""
        for record in (self.journal, self.decisions):
            if record is not None:
                with contextlib.suppress(OSError):  # the empty file of a run never started
                    record.close()

    def discard(self) -> None:
        """Close and remove the files of a run that never started (nothing was recorded):
        a journal holding its header alone is no record of a run, and no replay reads it."""
        self.close()
        if self.directory is not None:
            for record in (self.journal, self.decisions):
                if record is not None:
                    record.path.unlink(missing_ok=True)
            self.directory.rmdir()
        self.directory = self.journal = self.decisions = None


@dataclass
class RunContext:
    manifest: Manifest
    cell: Cell
    recorder: Recorder
    files: RunFiles
    sections: ScenarioSections
    """The sections the journal's header carries (what rebuilds this run's core exactly)."""
    summary: RunSummary = field(default_factory=RunSummary)
    lateness_ns: list[int] = field(default_factory=list)
    misses: int = 0
    periods_skipped: int = 0
    longest_gap_ns: int = 0
    """The longest time between two ticks' wake-ups (a stall; lateness cannot show one)."""
    last_woke_ns: int | None = None
    heartbeat: HeartbeatStats | None = None
    """The safety monitor's heartbeat as sent so far (a live run with ``[safety]``)."""


def open_run(manifest: Manifest, clock: Clock, journal_dir: Path | None,
             progress: CycleProgress | None) -> RunContext:
    """The run's files, the world and the cell; on any failure nothing is left running.

    The files come first: a directory that cannot hold the run's record is refused before
    any device or emulator starts.

    Raises:
        ManifestError: the files cannot be made (naming the directory), or the cell cannot
            be built.
    """
    files = RunFiles.open(journal_dir, manifest.name)
    note_run_directory(files.directory)  # in the device's lock, for a second warden to name
    try:
        world = world_for(manifest)
    except BaseException:
        files.discard()
        raise
    recorder: Recorder | None = None
    try:
        config, sections = effective(manifest, world)
        head = {**header(sections.document(), manifest.name),
                "provenance": provenance(manifest.digest, manifest.path, manifest.signer)}
        recorder = _recorder(files, head)
        cell = build_cell(manifest, config, world, clock, recorder)
    except BaseException:
        world.close()  # an emulator already started must not outlive a failed build
        if recorder is not None:
            recorder.close()
        with contextlib.suppress(OSError):  # a directory that failed: the error says so
            files.discard()
        raise
    context = RunContext(manifest, cell, recorder, files, sections)
    cell.gateway.listeners.append(context.summary.observe_all)
    cell.controller.on_cycle = _on_cycle(context, progress)
    return context


def close_record(context: RunContext) -> None:
    """Close the run's record; a run that recorded nothing (refused or stopped before its
    first tick) leaves no run directory."""
    context.recorder.close()
    stats = context.recorder.stats
    if stats.events == 0 and stats.lines == 0 and stats.error is None:
        with contextlib.suppress(OSError):  # kept then, and said so in the summary
            context.files.discard()


def cut_short_reason(context: RunContext, stop: StopSignals, failures: list[str],
                     ended_by_hook: bool = False) -> str:
    """Why a run ended with a cycle under way (what :meth:`ControlLoop.cut_short` records)."""
    if stop.received is not None:
        return f"interrupted by {stop.received.name}"
    if context.cell.controller.record_failed:
        return "the run's record could not be written"
    if failures:
        return f"a task failed: {failures[0]}"
    if ended_by_hook:
        return "the run was ended before the cycle finished"
    return "the run's time (cell.cycle_timeout_s per cycle) ran out"


def _recorder(files: RunFiles, head: dict[str, Any]) -> Recorder:
    """Raises:
        ManifestError: the journal's header cannot be written.
    """
    try:
        return Recorder(files.journal, files.decisions, head)
    except OSError as error:
        raise ManifestError(f"{files.directory}: cannot record the run there: "
                            f"{error.strerror or error}") from error


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
        v_max=tuple(limits.velocity[arm].tolist()),
        a_max=tuple(limits.acceleration[arm].tolist()))


def report_progress(context: RunContext, progress: CycleProgress | None) -> None:
    if progress is None:
        return
    core = context.cell.core.status()
    controller = context.cell.controller
    progress.update(min(len(controller.results) + 1, controller.cycles),
                    str(context.cell.controller.runner.step), str(core.phase), str(core.mode))


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
    if context.last_woke_ns is not None:  # a timer paced the loop (a wall-clock run)
        summary.loop.update(longest_gap_ms=round(context.longest_gap_ns / 1e6, 3),
                            periods_skipped=context.periods_skipped)
        log.info("control loop", ticks=ticks, misses=context.misses,
                 longest_gap_ms=summary.loop["longest_gap_ms"],
                 periods_skipped=context.periods_skipped)
    summary.extra.update(extra)
    cut = context.cell.controller.cut
    summary.extra["cycle_cut_short"] = cut.index if cut is not None else None
    stats = context.recorder.stats
    journal: dict[str, Any] = {"directory": str(context.files.directory or "-"),
                               "events": stats.events, "gaps": stats.gaps, "error": stats.error}
    if stats.error is not None:  # what became of the run when its record failed
        journal.update(fault=context.recorder.fault,
                       core_told=context.cell.controller.record_failed,
                       tail_written=stats.tail_written, tail_error=stats.tail_error,
                       files=context.recorder.files())
    summary.extra["journal"] = journal
    summary.extra["driver"] = {"refused_writes": context.cell.controller.counters.refused_writes,
                               "faults": "; ".join(context.cell.controller.counters.driver_faults)
                               or "none"}
    data = summary.as_dict()
    if context.files.directory is not None:
        try:
            (context.files.directory / "summary.json").write_text(json.dumps(data, indent=1,
                                                                             default=str))
        except OSError as error:  # the disk that failed the record: stderr carries it
            data["journal"]["summary_file"] = f"not written: {error.strerror or error}"
    return data


def _lateness(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    stats = percentiles(values)
    ordered = sorted(values)
    stats["p99"] = ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]
    stats["p999"] = ordered[min(len(ordered) - 1, int(0.999 * len(ordered)))]
    return stats
