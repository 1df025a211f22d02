"""The cell on the wall clock: a kernel timer paces the control loop, the policy server runs as
a separate process on loopback, and the policy link talks to it over a real websocket.

Tasks live in one supervisor: the recorder, the control loop and the job worker are critical
(their failure ends the run, after the arm is held), the policy link is not (a crash is a lost
link: the core degrades, the link is restarted and must handshake again).
"""

from __future__ import annotations

import asyncio
import functools
import gc
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import structlog

from kernel.app import standins
from kernel.app.cameras import camera_hub, frame_store
from kernel.app.compose import source_of
from kernel.app.interrupt import StopSignals
from kernel.app.operator import operator_server
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
from kernel.core.events import LinkEvent, LinkStatus
from kernel.manifest import Manifest, ManifestError
from kernel.shell.cameras import CameraHub
from kernel.shell.client import RobotClient
from kernel.shell.frame_store import FrameStore
from kernel.shell.heartbeat import HeartbeatSender
from kernel.shell.link_budget import AdmissionPacer
from kernel.shell.link_types import ClientConfig
from kernel.shell.metrics import MetricsEndpoint, MetricsUnavailable
from kernel.shell.operator import OperatorServer
from kernel.shell.realtime import log_report, restore, try_realtime
from kernel.shell.supervisor import RestartPolicy, Supervisor, describe, failure_fields
from kernel.shell.systemd import ServiceNotifier
from kernel.shell.timer import MonotonicClock, PeriodicTimer, Tick
from kernel.shell.worker import JobWorker

log = structlog.get_logger("warden.run")
EARLY_WAKE_NS = 200_000
"""Wake this long before each deadline and spin the rest: a timerfd wake-up alone is late by
hundreds of microseconds at p99 under load (bench/loop.py measures both)."""


STALL_PERIODS = 25
"""Without a state watchdog, a gap of this many periods is logged as a stall."""

TickHook = Callable[[RunContext], bool]
"""Called after every control tick (tests and fault campaigns); returning True ends the run."""


async def run_live(manifest: Manifest, journal_dir: Path | None,
                   progress: CycleProgress | None = None,
                   hook: TickHook | None = None) -> dict[str, Any]:
    """The run, from start-up to summary, with SIGINT and SIGTERM noted throughout (a stop
    requested at any point ends it in order: :mod:`kernel.app.interrupt`)."""
    with StopSignals() as stop:
        return await _run_live(manifest, journal_dir, progress, hook, stop)


async def _run_live(manifest: Manifest, journal_dir: Path | None,
                    progress: CycleProgress | None, hook: TickHook | None,
                    stop: StopSignals) -> dict[str, Any]:
    metrics = metrics_endpoint(manifest)  # a port that is taken: exit 2, before anything opens
    try:
        context = open_run(manifest, MonotonicClock(), journal_dir, progress)
    except BaseException:
        if metrics is not None:
            metrics.close()
        raise
    try:
        operator = operator_server(context.cell)
    except BaseException:
        context.cell.world.close()
        close_record(context)
        if metrics is not None:
            metrics.close()
        raise
    server: _Launched | None = None
    worker = JobWorker(context.cell.gateway, context.sections, source_of(manifest))
    realtime = try_realtime()
    log_report(log, realtime)
    service = ServiceNotifier.from_env()
    failures: list[str] = []
    loop = _Loop(context, progress, hook, service, realtime.summary(), stop)
    loop.heartbeat = _heartbeat(manifest)
    context.heartbeat = loop.heartbeat.stats if loop.heartbeat.enabled else None
    client: RobotClient | None = None
    cameras: CameraHub | None = None
    frames: FrameStore | None = None
    try:
        # A stop requested during start-up (device bring-up, policy server start) is kept and
        # honoured before the first tick, through the same orderly shutdown.
        worker.start()
        await bring_up(context)  # a device that is not there fails here, before anything
        security = manifest.link_security
        url = f"{security.scheme}://{manifest.policy.host}:{manifest.policy.port}"
        if not stop.requested and manifest.policy.launch:
            server = _Launched(standins.load(standins.POLICIES, "reference")(
                context.cell.context))
            url = server.start()
        if not stop.requested:
            frames = frame_store(manifest, context.files.directory)
            cameras = camera_hub(manifest, context.cell.world, context.cell.gateway.now_ns,
                                 frames.keep if frames is not None else None)
        if cameras is not None:  # every camera sees before anything moves
            cameras.start()
            await asyncio.to_thread(cameras.wait_first_frames)
        if not stop.requested:
            client = RobotClient(ClientConfig(url=url, policy=manifest.policy,
                                              security=security),
                                 context.cell.gateway, pacer=loop.pacer, server=server,
                                 cameras=cameras)
            if metrics is not None:
                metrics.start()
            await _supervise(context, client, worker, operator, loop, failures, cameras,
                             metrics)
    finally:
        context.cell.controller.cut_short(cut_short_reason(
            context, stop, failures, ended_by_hook=loop.ended_by_hook))
        service.stopping("holding the arm and closing the device")
        await context.cell.driver.aclose()
        loop.heartbeat.close()  # END only now: the arm is held and the device closed
        context.cell.world.close()
        if cameras is not None:  # after the arm is held: a read that hangs delays nothing
            await asyncio.to_thread(_stop_cameras, cameras)
        if frames is not None:
            await asyncio.to_thread(frames.close)
        worker.close()
        gc.unfreeze()  # let the collector see the run's objects again before the process ends
        restore(realtime)
        service.close()
        if server is not None:
            await asyncio.to_thread(server.stop)  # after a restart still under way, if any
        if metrics is not None:
            await asyncio.to_thread(metrics.close)
        close_record(context)
    return finish(context, {
        "clock": "wall", "stopped": stop.requested,
        "interrupted": stop.received.name if stop.received else None,
        "timed_out": not (context.cell.controller.finished or stop.requested
                          or context.cell.controller.record_failed),
        "task_failures": failures, "loop": {"realtime": realtime.summary()},
        "link": {k: v for k, v in client.counters.snapshot().items() if v} if client else {},
        "jobs": {"done": worker.done, "failed": worker.failed},
        "operator": _operator_summary(operator), "safety": loop.heartbeat.summary(),
        **({"frames": frames.stats.as_dict()} if frames is not None else {}),
        **({"metrics": {"port": metrics.port, "exporter_exit": metrics.exit_code}}
           if metrics is not None else {}),
        "service": {"notify": service.enabled, "sent": service.stats.sent,
                    "failed": service.stats.failed},
    })


def metrics_endpoint(manifest: Manifest) -> MetricsEndpoint | None:
    """``[metrics]``'s socket, bound now. Raises:
        ManifestError: the port cannot be bound (naming ``metrics.port``)."""
    settings = manifest.metrics
    if settings is None:
        return None
    try:
        return MetricsEndpoint(settings.host, settings.port)
    except MetricsUnavailable as error:
        key = "metrics" + (f".{error.key}" if error.key else "")
        raise ManifestError(f"{manifest.path}: {key}: {error}") from None


def _loop_counts(context: RunContext) -> dict[str, int]:
    return {"journal_gaps": context.recorder.stats.gaps, "deadline_misses": context.misses}


class _Launched:
    """The policy server this run started (a stand-in reached through the registry): the link
    restarts it when it falls silent or refuses connections. Starting waits for the child's
    READY line, so it runs on a thread, never on the loop; a lock keeps a restart and the final
    stop from overlapping (the final stop waits for a restart under way, then stops it)."""

    def __init__(self, server: Any) -> None:
        self._server = server
        self._lock = threading.Lock()

    def start(self) -> str:
        with self._lock:
            return str(self._server.start())

    def stop(self) -> None:
        with self._lock:
            self._server.stop()

    async def restart(self) -> str:
        return await asyncio.to_thread(self._cycle)

    def _cycle(self) -> str:
        with self._lock:
            self._server.stop()
            return str(self._server.start())


class _Loop:
    """The control loop and what it reports: progress, the tick hook, the service manager.

    After each tick it opens the period's admission window (:class:`AdmissionPacer`): chunk
    admissions run right after the tick, or later only while half a period remains, so the
    policy link's work never pushes a tick past its deadline."""

    def __init__(self, context: RunContext, progress: CycleProgress | None,
                 hook: TickHook | None, service: ServiceNotifier, scheduling: str,
                 stop: StopSignals) -> None:
        self.context, self.progress, self.hook = context, progress, hook
        self.service, self.scheduling, self.stop = service, scheduling, stop
        self.ended_by_hook = False
        self.heartbeat = HeartbeatSender(None)
        self._status = ""
        period = context.cell.core.config.control_period_ns
        timeout = context.cell.core.config.state_timeout_ns
        self.stall_ns = timeout if timeout is not None else STALL_PERIODS * period
        """A gap between ticks longer than this is logged as a stall (the state watchdog)."""
        self.pacer = AdmissionPacer(context.manifest.policy.admissions_per_period, period // 2)

    async def run(self) -> None:
        manifest, cell = self.context.manifest, self.context.cell
        period = cell.core.config.control_period_ns
        budget_ns = round(manifest.cell.cycle_timeout_s * 1e9) * manifest.cell.cycles
        cell.controller.start()
        # A device's one blocking step before streaming (the UR controller's watchdog) goes
        # here, before the timer starts, not into the first tick.
        await cell.driver.before_first_tick()
        async with PeriodicTimer(period, early_ns=EARLY_WAKE_NS) as timer:
            while not (cell.controller.finished or self.stop.requested
                       or cell.controller.record_failed) and cell.gateway.now_ns() < budget_ns:
                tick = await timer.wait()
                self._timed(tick, period)
                await cell.controller.tick(tick.skipped)
                self.pacer.period_done(tick.deadline_ns + period)
                self.service.alive()  # only a loop that completes its ticks feeds the watchdog
                self.heartbeat.beat()  # ... and the safety monitor's heartbeat
                self._report()
                if self.hook is not None and self.hook(self.context):
                    self.ended_by_hook = True
                    break
        self.heartbeat.closing()  # ended in order (an error skips this: the monitor stops)

    def _timed(self, tick: Tick, period: int) -> None:
        """Lateness within the period, misses, and the gap since the previous tick: a stall
        shows only there (lateness is measured from the latest deadline, so it stays under
        one period however long the loop stood still). A stall past the state watchdog is
        logged here; the core makes it a WATCHDOG fault from the tick times."""
        context = self.context
        context.lateness_ns.append(tick.lateness_ns)
        if tick.skipped or tick.lateness_ns > period // 2:
            context.misses += max(1, tick.skipped)
        context.periods_skipped += tick.skipped
        if context.last_woke_ns is not None:
            gap = tick.woke_ns - context.last_woke_ns
            context.longest_gap_ns = max(context.longest_gap_ns, gap)
            if gap > self.stall_ns:
                log.error("control loop stalled", gap_ms=round(gap / 1e6, 1),
                          periods_skipped=tick.skipped, watchdog_ms=self.stall_ns / 1e6)
        context.last_woke_ns = tick.woke_ns

    def _report(self) -> None:
        report_progress(self.context, self.progress)
        if not self.service.enabled:
            return  # no systemd to tell: do not build a status line every tick
        cell = self.context.cell
        status = (f"cycle {min(len(cell.controller.results) + 1, cell.controller.cycles)}: "
                  f"{cell.controller.runner.step} ({cell.core.status().mode})")
        if status != self._status:
            self._status = status
            self.service.status(status)


async def _supervise(context: RunContext, client: RobotClient, worker: JobWorker,
                     operator: OperatorServer | None, loop: _Loop, failures: list[str],
                     cameras: CameraHub | None, metrics: MetricsEndpoint | None) -> None:
    def failed(name: str, error: BaseException) -> None:
        task_failed(context, failures, name, error)

    done = asyncio.Event()

    async def link(started) -> None:  # type: ignore[no-untyped-def]
        started()
        await client.run()

    async def control(started) -> None:  # type: ignore[no-untyped-def]
        # Everything allocated so far lives for the whole run: keep it out of the collector's
        # way, so a full collection does not pause the control loop for 100 ms.
        gc.collect()
        gc.freeze()
        started()
        loop.service.ready(f"{context.manifest.name}: {context.manifest.driver_name} ready; "
                           f"{loop.scheduling}")
        try:
            await loop.run()
        finally:
            context.cell.gateway.close()
            done.set()

    async with Supervisor(on_failure=failed) as supervisor:
        await supervisor.start("recorder", context.recorder.run, critical=True)
        await supervisor.start("jobs", worker.run, critical=True)
        if operator is not None:  # a real device's only way back from a fallback: critical
            await supervisor.start("operator", operator.run, critical=context.cell.real_device)
        if cameras is not None:  # unwatched, a lost camera would never reach the core
            gateway = context.cell.gateway
            await supervisor.start("cameras", functools.partial(
                cameras.watch, gateway.now_ns, gateway.feed), critical=True)
        await supervisor.start("policy-link", link, critical=False,
                               restart=RestartPolicy(max_restarts=10))
        if metrics is not None:  # evidence, not control: its failure ends nothing
            settings = context.manifest.metrics
            interval_s = settings.publish_interval_ms / 1e3 if settings else 0.5
            await supervisor.start("metrics", functools.partial(
                metrics.publisher.run, summary=context.summary,
                links=client.counters.snapshot, loop=functools.partial(_loop_counts, context),
                interval_s=interval_s), critical=False)
        await supervisor.start("control", control, critical=True)
        await done.wait()
        client.stop()
        await supervisor.shutdown()


def _stop_cameras(cameras: CameraHub) -> None:
    stuck = cameras.stop()
    if stuck:
        log.warning("camera still in a read at the run's end", cameras=stuck)


def _heartbeat(manifest: Manifest) -> HeartbeatSender:
    safety = manifest.safety
    if safety is None:
        return HeartbeatSender(None)
    return HeartbeatSender(safety.heartbeat_path, safety.heartbeat_periods)


def _operator_summary(operator: OperatorServer | None) -> dict[str, Any]:
    if operator is None:
        return {"socket": "-"}
    stats = operator.stats
    return {"socket": str(operator.path), "granted": stats.granted, "refused": stats.refused,
            "takeover_latency_ms": stats.takeover_latency_ms}


def task_failed(context: RunContext, failures: list[str], name: str,
                error: BaseException) -> None:
    """A supervised task died: never silently. A dead policy link is a lost link for the core
    (LINK_LOST → DEGRADED: the arm holds until a new handshake); the critical tasks (control,
    recorder) end the run, and the run's shutdown holds the arm and closes the device."""
    failures.append(f"{name}: {describe(error)}")
    log.error("task failed", task=name, **failure_fields(error))
    if name == "policy-link":
        gateway = context.cell.gateway
        gateway.feed(LinkEvent(t=gateway.now_ns(), status=LinkStatus.DOWN))
