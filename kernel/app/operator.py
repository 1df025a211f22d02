"""The operator socket of a run: where it is, who may use it, and whether the run needs it.

A run on a real device has no simulated operator: a human is the only way back from a fallback,
so its operator socket must be served, and a run that cannot serve it does not start (exit 2,
before the device is touched). In simulation the socket is served where it can be, and a run
goes on without it (with a log line) where it cannot.
"""

from __future__ import annotations

import grp
import os
from pathlib import Path
from typing import Any

import structlog

from kernel.app.compose import Cell
from kernel.manifest import ManifestError
from kernel.shell.operator import OperatorServer, socket_path

log = structlog.get_logger("warden.operator")


def operator_server(cell: Cell) -> OperatorServer | None:
    """The run's operator server, or None (simulation, and no usable runtime directory).

    Raises:
        ManifestError: a real device's operator socket cannot be served (no such group, no
            runtime directory to put it in).
    """
    settings, where = cell.manifest.operator, f"{cell.manifest.path}: operator"
    required = cell.real_device
    path = socket_path(settings.socket)
    group = settings.group or grp.getgrgid(os.getegid()).gr_name
    try:
        grp.getgrnam(group)
    except KeyError:
        raise ManifestError(f"{where}.group: no group {group!r} on this host") from None
    problem = _unusable(path)
    if problem:
        if required:
            raise ManifestError(f"{where}.socket: cannot serve the operator socket at {path}: "
                                f"{problem} (a real device needs a human's authority)")
        log.warning("no operator socket", path=str(path), detail=problem)
        return None
    return OperatorServer(cell.gateway, path, group, lambda: status(cell))


def _unusable(path: Path) -> str:
    directory = path.parent
    if not directory.is_dir():
        return f"{directory} is not a directory (systemd's RuntimeDirectory= makes it)"
    if not os.access(directory, os.W_OK | os.X_OK):
        return f"{directory} is not writable by this user"
    return ""


def status(cell: Cell) -> dict[str, Any]:
    """What ``warden operator status`` shows."""
    core = cell.core.status()
    controller = cell.controller
    return {"run": cell.manifest.name, "mode": str(core.mode),
            "cause": str(core.cause) if core.cause else None,
            "phase": str(core.phase), "queue_epoch": core.epoch,
            "cycle": min(len(controller.results) + 1, controller.cycles),
            "step": str(controller.runner.step), "driver": str(cell.driver.state)}
