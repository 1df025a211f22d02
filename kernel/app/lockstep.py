"""The cell on a virtual clock: plant, policy and core step together, as fast as they can.

Deterministic for a given manifest and seed: the policy runs in process with seeded latency
and noise, admission's long work runs inline at the instant it is asked for, and every tick
advances the virtual clock by exactly one control period.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from kernel.app import standins
from kernel.app.interrupt import StopSignals
from kernel.app.report import CycleProgress
from kernel.app.session import (
    RunContext,
    bring_up,
    close_record,
    cut_short_reason,
    finish,
    open_run,
    report_progress,
)
from kernel.manifest import Manifest, ManifestError
from kernel.shell.timer import VirtualClock
from kernel.shell.worker import InlineJobs


async def run_lockstep(manifest: Manifest, journal_dir: Path | None,
                       progress: CycleProgress | None = None,
                       hook: Callable[[RunContext], bool] | None = None) -> dict[str, Any]:
    """``hook``: called after every tick, as a live run's is; True ends the run (tests)."""
    if manifest.driver_name != "sim":
        raise ManifestError(f"{manifest.path}: cell.clock: a virtual clock needs the in-process "
                            f"plant (driver 'sim'); {manifest.driver_name!r} runs in real time")
    with StopSignals() as stop:  # SIGINT, SIGTERM: end in order (kernel.app.interrupt)
        return await _run(manifest, journal_dir, progress, stop, hook)


async def _run(manifest: Manifest, journal_dir: Path | None, progress: CycleProgress | None,
               stop: StopSignals,
               hook: Callable[[RunContext], bool] | None) -> dict[str, Any]:
    clock = VirtualClock()
    context = open_run(manifest, clock, journal_dir, progress)
    cell = context.cell
    jobs = InlineJobs(cell.gateway)
    link = standins.load(standins.POLICIES, "local")(cell.context, clock)
    period = cell.core.config.control_period_ns
    budget_ns = round(manifest.cell.cycle_timeout_s * 1e9) * manifest.cell.cycles
    ended_by_hook = False
    try:
        await bring_up(context)
        link.connect()
        if not stop.requested:
            cell.controller.start()
        while not (cell.controller.finished or cell.controller.record_failed
                   or stop.requested) and cell.gateway.now_ns() < budget_ns:
            link.deliver_due()
            await cell.controller.tick()
            context.recorder.hand_over_if_due()
            report_progress(context, progress)
            if hook is not None and hook(context):
                ended_by_hook = True
                break
            clock.advance(period)
    finally:
        cell.controller.cut_short(cut_short_reason(context, stop, [], ended_by_hook))
        await cell.driver.aclose()
        cell.world.close()
        close_record(context)
    timed_out = not (cell.controller.finished or cell.controller.record_failed or stop.requested)
    return finish(context, {"clock": "virtual", "timed_out": timed_out, "stopped": stop.requested,
                            "interrupted": stop.received.name if stop.received else None,
                            "link": {"requests": link.requests}, "jobs": {"done": jobs.done}})
