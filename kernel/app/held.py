"""A held start (``warden run --await-confirmation``, the shipped unit's): nothing moves until a
human says so.

The run is checked as far as it can be without a device (the manifest and its signature, the
journal directory, the operator socket), then it holds: no device is opened, no emulator or
policy server started. It serves the operator socket, where ``warden operator status`` answers
``awaiting confirmation`` and ``warden operator confirm`` (a member of the operator group, by
SO_PEERCRED) starts the run; every other command is refused. Under systemd the unit is ready
while held (``READY=1``, ``STATUS=held: ...``), so a boot does not wait for a human, and the
hold pings the watchdog: it is the process's loop until the run's own loop starts. Between the
confirmation and that loop the device is brought up, which may take longer than the watchdog's
2 s: the timeout is lengthened to the bring-up's bound for that stretch and the loop's
``READY=1`` restores it.

So neither a boot nor a restart after a crash (``Restart=on-failure``) moves the arm: each
start of the process holds again.
"""

from __future__ import annotations

import asyncio
import contextlib
import grp
import os
import signal
import sys
from pathlib import Path

import structlog

from kernel.app.trial_socket import socket_problem
from kernel.manifest import Manifest, ManifestError
from kernel.shell.operator import Caller, await_confirmation, socket_path
from kernel.shell.systemd import ServiceNotifier

log = structlog.get_logger("warden.run")
BRING_UP_BOUND_S = 90.0
"""How long the device's bring-up may go without a watchdog ping after the confirmation: the
unit's ``TimeoutStartSec=``, the bound the same bring-up has at an ordinary start."""
FOREVER_S = 10 * 365 * 86_400.0
"""A held service waits for its operator as long as it runs."""


class HeldStopped(Exception):
    """SIGTERM (``systemctl stop``) or SIGINT while held: nothing was started or moved; the
    process exits 128 + the signal's number (143, 130), as an interrupted run does."""

    def __init__(self, signum: signal.Signals, run: str) -> None:
        super().__init__(f"{run}: stopped while held by {signum.name}: nothing was started "
                         "or moved")
        self.exit_code = 128 + int(signum)


def hold_until_confirmed(manifest: Manifest, timeout_s: float | None = None) -> int:
    """Hold until a member of the operator group confirms; the uid that did.

    Raises:
        ManifestError: the operator socket cannot be served (nothing was started), or
            nobody confirmed within ``timeout_s``.
        HeldStopped: SIGTERM or SIGINT while held.
    """
    where = f"{manifest.path}: operator"
    group = manifest.operator.group or grp.getgrgid(os.getegid()).gr_name
    try:
        grp.getgrnam(group)
    except KeyError:
        raise ManifestError(f"{where}.group: no group {group!r} on this host") from None
    path = socket_path(manifest.operator.socket)
    problem = socket_problem(path)
    if problem:
        raise ManifestError(f"{where}.socket: cannot serve the operator socket at {path}: "
                            f"{problem}")
    service = ServiceNotifier.from_env()
    try:
        caller = asyncio.run(_held(manifest, path, group, timeout_s or FOREVER_S, service))
    finally:
        service.close()
    return caller.uid


async def _held(manifest: Manifest, path: Path, group: str, timeout_s: float,
                service: ServiceNotifier) -> Caller:
    status = f"held: nothing moves until `warden operator confirm --socket {path}`"
    log.info("held", run=manifest.name, socket=str(path), group=group)
    print(f"warden: {manifest.name}: {status}", file=sys.stderr, flush=True)
    path.unlink(missing_ok=True)  # nobody answers there (socket_problem): a run that died
    waiting = asyncio.ensure_future(await_confirmation(path, group, manifest.name, timeout_s))
    loop = asyncio.get_running_loop()
    received: list[signal.Signals] = []

    def stop(signum: signal.Signals) -> None:
        received.append(signum)
        waiting.cancel()

    for signum in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(signum, stop, signum)
    try:
        # Ready once `warden operator` can reach the socket (the hold's only way out).
        while not (path.is_socket() or waiting.done()):
            await asyncio.sleep(0.01)
        service.ready(status)
        while not waiting.done():
            service.alive()  # rate-limited to half the watchdog's interval
            await asyncio.wait({waiting}, timeout=0.25)
        caller = waiting.result()
    except asyncio.CancelledError:
        raise HeldStopped(received[0] if received else signal.SIGTERM, manifest.name) from None
    except TimeoutError:
        raise ManifestError(f"{manifest.path}: not confirmed within {timeout_s:g} s (nothing "
                            "moved)") from None
    except (OSError, KeyError) as error:
        raise ManifestError(f"{manifest.path}: operator.socket: cannot wait for a "
                            f"confirmation at {path}: {error}") from None
    finally:
        for signum in (signal.SIGTERM, signal.SIGINT):
            loop.remove_signal_handler(signum)
        if not waiting.done():
            waiting.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await waiting
    service.extend_watchdog(BRING_UP_BOUND_S)
    service.status(f"confirmed by uid {caller.uid}: bringing the device up")
    log.info("confirmed", run=manifest.name, uid=caller.uid, pid=caller.pid)
    return caller
