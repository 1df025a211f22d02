"""``warden safety MANIFEST``: bring the monitor up, run it until SIGTERM, take it down.

Start-up refuses (exit 2, one line naming the key or the device and what to check) before any
stop could be sent: a manifest without ``[safety]``, a device the monitor has no watch for, a
missing force limit where the wrist sensor is read, a socket another monitor holds, a device
that does not answer. Only then does the monitor tell systemd it is ready (``READY=1``), so a
unit ordered after it starts on a monitor that is already watching.
"""

from __future__ import annotations

import contextlib
import grp
import os
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import structlog

from kernel.safety.checks import Limits
from kernel.safety.devices import watch_for
from kernel.safety.heartbeat import HeartbeatReceiver
from kernel.safety.monitor import Monitor
from kernel.safety.settings import SafetySettings
from kernel.safety.status import StatusServer, socket_problem
from kernel.safety.view import MonitorView, ViewError, read_view
from kernel.safety.watch import DeviceUnreachable, DeviceWatch
from kernel.shell.device_lock import DeviceBusy, Holder, holding
from kernel.shell.realtime import log_report, restore, try_realtime
from kernel.shell.systemd import ServiceNotifier

if TYPE_CHECKING:
    from kernel.safety.space import SpaceCheck

log = structlog.get_logger("warden.safety")
PRIORITY = 60
"""SCHED_FIFO priority of the monitor's loop: above warden's loop (50), so a warden loop that
spins at real-time priority cannot starve the process that watches it."""
FORCE_READ_BY = frozenset({"ur_rtde", "sim"})


class StartError(Exception):
    """The monitor cannot start; the message says why and what to check (exit 2)."""


@dataclass(frozen=True, slots=True)
class Plan:
    manifest: MonitorView
    settings: SafetySettings
    limits: Limits
    gid: int
    space: SpaceCheck | None = None


def plan(path: str) -> Plan:
    """The monitor's view of the manifest, checked for everything the monitor needs.

    Raises:
        StartError: what is missing or wrong, naming the file and the key.
    """
    try:
        manifest = read_view(path)
    except ViewError as error:
        raise StartError(str(error)) from None
    settings = manifest.safety
    if settings is None:
        raise StartError(f"{manifest.path}: safety: no [safety] table; the monitor needs at "
                         "least safety.max_wrist_force_n (docs/manifest.md, '[safety]')")
    if manifest.driver_name in FORCE_READ_BY and settings.max_wrist_force_n is None:
        raise StartError(f"{manifest.path}: safety.max_wrist_force_n: required key is missing "
                         f"(the monitor reads the {manifest.driver_name} wrist sensor and needs "
                         "a limit somebody chose)")
    group = settings.group or grp.getgrgid(os.getegid()).gr_name
    try:
        gid = grp.getgrnam(group).gr_gid
    except KeyError:
        raise StartError(f"{manifest.path}: safety.group: no group {group!r} on this "
                         "host") from None
    limits = Limits.of(manifest.limits, settings)
    return Plan(manifest, settings, limits, gid, _space(manifest, len(limits.lower)))


def _space(manifest: MonitorView, dof: int) -> SpaceCheck | None:
    """The space check of ``[geometry]``, or None when it names no solid the monitor checks.

    Raises:
        StartError: solids to check and no arm model to check them against, or a model
            MuJoCo cannot load.
    """
    geometry = manifest.geometry
    if geometry is None or not (geometry.obstacles or geometry.keep_out):
        return None
    # MuJoCo is loaded only here: a monitor of a cell without solids never imports it.
    from kernel.safety.space import SpaceCheck, SpaceModelError
    if manifest.arm_model is None:
        raise StartError(f"{manifest.path}: robot.kinematics: the monitor checks the arm "
                         "against [geometry] and needs the arm's model ('kinematics' or "
                         "'model')")
    try:
        return SpaceCheck(manifest.arm_model, dof, geometry)
    except SpaceModelError as error:
        raise StartError(f"{manifest.path}: robot.model: {error}") from None


def serve(path: str) -> None:
    """Run the monitor until SIGTERM or SIGINT.

    Raises:
        StartError: it could not start (nothing was commanded).
    """
    chosen = plan(path)
    settings = chosen.settings
    with contextlib.ExitStack() as stack:
        # Warden's own lock never blocks the monitor (a second client by design); a second
        # monitor on the same device is refused before it connects or raises its priority.
        try:
            stack.enter_context(holding(chosen.manifest, "warden safety", Holder.MONITOR))
        except DeviceBusy as error:
            raise StartError(f"cannot watch the device: {error}") from None
        heartbeat = _bound(lambda: HeartbeatReceiver(
            settings.heartbeat_path, chosen.gid, settings.heartbeat_timeout_ns,
            settings.closing_timeout_ns), "heartbeat", settings.heartbeat_path, chosen)
        stack.callback(heartbeat.close)
        watch = _connected(chosen)
        stack.callback(watch.close)
        monitor = Monitor(settings, chosen.limits, watch, heartbeat, space=chosen.space)
        manifest = chosen.manifest
        watched = {"name": manifest.name, "path": str(manifest.path.resolve()),
                   "digest": manifest.digest}  # a trial checks this is its own manifest
        status = _bound(lambda: StatusServer(
            settings.status_path, chosen.gid, lambda: {**monitor.status(), "manifest": watched}),
            "status", settings.status_path, chosen)
        stack.callback(status.close)
        _watch(chosen, monitor, status)


def _watch(chosen: Plan, monitor: Monitor, status: StatusServer) -> None:
    watch, settings = monitor.watch, chosen.settings
    realtime = try_realtime(PRIORITY)
    log_report(log, realtime)
    service = ServiceNotifier.from_env()
    stopping = SignalledStop()
    try:
        with stop_on_signals(stopping):
            monitor.check()  # one full check before anyone is told the monitor watches
            status.start()
            log.info("safety monitor watching", manifest=str(chosen.manifest.path),
                     device=watch.description, stop_path=watch.stop_path,
                     heartbeat=str(settings.heartbeat_path), status=str(settings.status_path),
                     timeout_ms=settings.heartbeat_timeout_ms, scheduling=realtime.in_effect(),
                     space=list(chosen.space.solids) if chosen.space else None)
            service.ready(f"watching {watch.description}")
            monitor.run(stopping, service.alive)
    finally:
        service.stopping("safety monitor stopping")
        service.close()
        restore(realtime)
    log.info("safety monitor stopped", checks=monitor.checks, stops=monitor.stop_count)


def _bound(make, what: str, path: Path, chosen: Plan):  # type: ignore[no-untyped-def]
    try:
        return make()
    except OSError as error:
        raise StartError(f"cannot serve the {what} socket {socket_problem(path, error)} "
                         f"({chosen.manifest.path}: safety.{what}_socket; the monitor's unit "
                         "makes /run/warden-safety with RuntimeDirectory=, anywhere else "
                         "create the directory first)") from None


def _connected(chosen: Plan) -> DeviceWatch:
    try:
        watch = watch_for(chosen.manifest, chosen.settings)
    except DeviceUnreachable as error:
        raise StartError(f"cannot watch the device: {error}") from None
    try:
        watch.connect()
    except DeviceUnreachable as error:
        watch.close()  # half open (the dashboard, not RTDE): nothing was sent on it
        raise StartError(f"cannot watch the device: {error}") from None
    return watch


class SignalledStop:
    """The monitor's stop, which SIGTERM or SIGINT requests: a plain flag, never a lock.

    A signal handler runs in the main thread between two of its bytecodes, and the monitor's
    main thread spends its life in the wait between two checks. With a ``threading.Event``
    there, a handler calling ``set()`` while ``wait()`` held the Event's lock waited for it
    forever: a monitor its test had stopped hung at real-time priority 60 until killed (and a
    systemd stop would have ended in SIGKILL). The wait is a sleep of one period at most, so a
    stop takes effect at the next check."""

    def __init__(self) -> None:
        self.requested = False

    def set(self) -> None:
        self.requested = True

    def is_set(self) -> bool:
        return self.requested

    def wait(self, timeout: float) -> bool:
        time.sleep(timeout)  # a signal's handler runs inside it; the sleep then ends as due
        return self.requested


@contextlib.contextmanager
def stop_on_signals(stopping: SignalledStop) -> Iterator[None]:
    previous = {signum: signal.signal(signum, lambda *_: stopping.set())
                for signum in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
