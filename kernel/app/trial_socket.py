"""Where a trial serves its operator socket, checked before anyone is asked to confirm.

The run's default, ``/run/warden/operator.sock``, lives in the directory systemd makes for
warden.service (``RuntimeDirectory=warden``) while that service runs, and a running service is
another warden, serving that socket itself. A trial started from a terminal therefore takes,
in this order: ``[operator] socket`` when the manifest names one; the service's runtime
directory when it runs under systemd (``RUNTIME_DIRECTORY``); ``/run/warden`` when it is there
and free; otherwise a directory of its own (``$XDG_RUNTIME_DIR`` or the temporary directory,
``warden-trial-*``, 0750 to the operator group), removed when the trial ends. The card names
the path, so ``warden operator ... --socket PATH`` reaches it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import grp
import os
import shutil
import socket
import tempfile
from collections.abc import Iterator
from pathlib import Path

import msgspec

from kernel.manifest import Manifest, ManifestError
from kernel.shell.operator import DEFAULT_RUNTIME_DIRECTORY, SOCKET_NAME, socket_path


@contextlib.contextmanager
def trial_socket(manifest: Manifest) -> Iterator[tuple[Manifest, Path]]:
    """The manifest with its operator socket set to where this trial serves it, and that path;
    a directory the trial made for it is removed on the way out.

    Raises:
        ManifestError: no such operator group, or the socket's directory is missing, not
            writable, or another warden serves the socket already.
    """
    settings, where = manifest.operator, f"{manifest.path}: operator"
    group = settings.group or grp.getgrgid(os.getegid()).gr_name
    try:
        gid = grp.getgrnam(group).gr_gid
    except KeyError:
        raise ManifestError(f"{where}.group: no group {group!r} on this host") from None
    made: Path | None = None
    path = socket_path(settings.socket)
    chosen = bool(settings.socket or os.environ.get("RUNTIME_DIRECTORY"))
    if not chosen and socket_problem(path) and path.parent == Path(DEFAULT_RUNTIME_DIRECTORY):
        made = _own_directory(gid)
        path = made / SOCKET_NAME
    try:
        problem = socket_problem(path)
        if problem:
            raise ManifestError(f"{where}.socket: cannot serve the operator socket at {path}: "
                                f"{problem}")
        operator = msgspec.structs.replace(settings, socket=str(path))
        yield dataclasses.replace(manifest, operator=operator), path
    finally:
        if made is not None:
            shutil.rmtree(made, ignore_errors=True)


def _own_directory(gid: int) -> Path:
    base = os.environ.get("XDG_RUNTIME_DIR") or None
    made = Path(tempfile.mkdtemp(prefix="warden-trial-", dir=base))
    if os.geteuid() == 0 or gid in os.getgroups():
        os.chown(made, -1, gid)
    made.chmod(0o750)  # the operator group may reach the socket (itself 0660), nobody else
    return made


def socket_problem(path: Path) -> str:
    """Why the operator socket cannot be served at ``path``, or "" (also for a held start,
    kernel/app/held.py)."""
    directory = path.parent
    if not directory.is_dir():
        return f"{directory} is not a directory"
    if not os.access(directory, os.W_OK | os.X_OK):
        return f"{directory} is not writable by this user"
    if path.is_socket() and _answers(path):
        return ("another warden serves it (a device has one master: stop it first, e.g. "
                "systemctl stop warden)")
    if path.exists() and not path.is_socket():
        return "a file that is not a socket is in the way"
    return ""


def _answers(path: Path) -> bool:
    probe = socket.socket(socket.AF_UNIX)
    try:
        probe.connect(str(path))
    except OSError:
        return False  # a socket left by a run that died: serving removes it
    finally:
        probe.close()
    return True
