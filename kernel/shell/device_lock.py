"""One warden per device: an flock(2) on a lock file named after the device's identity.

A second warden on a device the first one drives would take its drives out of OPERATIONAL,
grab its RTDE registers or answer its servos' status packets: the lock is taken before anything
touches the device, launches an emulator for it or raises the process to SCHED_FIFO, and a
second instance is refused (exit 2) naming the holder's pid, command, run and run directory.

The identity comes from the driver (``device_identity`` of its class, from the manifest's
``[driver]`` table): a UR controller's address, a Dynamixel serial port, a CAN interface and
channel. The kernel releases an flock when its holder exits, however it exits (SIGKILL too), so
a lock whose holder died is free again; lock files are never removed (unlinking a file another
process is about to lock would split the lock in two).

Two kinds of holder: ``warden`` (``warden run``, ``warden trial`` and ``warden check``, which
exclude each other) and ``monitor`` (``warden safety``, a second client of the device by design:
warden's lock never blocks it, but two monitors on one device are refused).

Where: ``$WARDEN_LOCK_DIR`` if set; otherwise ``/run/warden/locks`` for warden and
``/run/warden-safety/locks`` for the monitor (the systemd units' RuntimeDirectory=), or, when
that directory cannot be made (not root, no unit), ``/tmp/warden-locks-<uid>``.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any, Protocol

from drivers import registry
from drivers.base import DriverInitError

LOCK_DIR_ENV = "WARDEN_LOCK_DIR"


class Holder(StrEnum):
    WARDEN = "warden"
    MONITOR = "monitor"


DEFAULT_DIRS: dict[Holder, Path] = {Holder.WARDEN: Path("/run/warden/locks"),
                                    Holder.MONITOR: Path("/run/warden-safety/locks")}
SLUG_CHARS = 60


class _Emulator(Protocol):
    @property
    def launch(self) -> bool: ...


class Addressed(Protocol):
    """What the lock reads of a manifest: warden's :class:`kernel.manifest.Manifest` and the
    safety monitor's own view (:class:`kernel.safety.view.MonitorView`) both have it, so the
    monitor takes the lock without loading warden's configuration."""

    @property
    def name(self) -> str: ...
    @property
    def path(self) -> Path: ...
    @property
    def driver_name(self) -> str: ...
    @property
    def driver_settings(self) -> Any: ...
    @property
    def emulator(self) -> _Emulator: ...


class DeviceBusy(DriverInitError):
    """Another warden (or monitor) holds the device's lock; the message names it."""


@dataclass(eq=False)
class DeviceLock:
    """A held lock: the open file whose flock it is, and what the file says about us."""

    path: Path
    fd: int
    device: str
    record: dict[str, Any]

    def note(self, **fields: Any) -> None:
        """Add to what the lock file says about its holder (the run directory, once made)."""
        self.record.update({key: str(value) for key, value in fields.items()})
        _write(self.fd, self.record)

    def release(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)  # closing the last descriptor releases the flock
            self.fd = -1
            _HELD.remove(self)


_HELD: list[DeviceLock] = []
"""The locks this process holds (a run notes its directory in each)."""


def device_of(manifest: Addressed) -> str | None:
    """The identity of the device a manifest's driver addresses; None when no other process
    could reach it (the in-process plant, python-can's virtual bus, an emulator this run
    launches for itself at an address of its own)."""
    if manifest.emulator.launch or manifest.driver_name == "sim":
        return None
    try:
        driver = registry.load(manifest.driver_name)
    except registry.UnknownDriver:
        return None  # refused by name when the manifest is loaded
    return driver.device_identity(manifest.driver_settings)


@contextlib.contextmanager
def holding(manifest: Addressed, command: str,
            holder: Holder = Holder.WARDEN) -> Iterator[DeviceLock | None]:
    """The device lock for ``manifest``'s device while the block runs (None: no device to lock).

    Raises:
        DeviceBusy: another process holds it (naming its pid, command, run and directory), or
            the lock cannot be taken at all (naming the directory).
    """
    device = device_of(manifest)
    if device is None:
        yield None
        return
    lock = acquire(device, holder, {"command": command, "run": manifest.name,
                                    "manifest": str(manifest.path)})
    try:
        yield lock
    finally:
        lock.release()


def acquire(device: str, holder: Holder, about: dict[str, str]) -> DeviceLock:
    """Take the lock of ``device`` for a ``holder``, recording our pid and ``about``.

    Raises:
        DeviceBusy: as :func:`holding`.
    """
    path = lock_directory(holder, device) / _file_name(holder, device)
    fd = _open(path, device)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder_record = _read(fd)
        os.close(fd)
        raise DeviceBusy(device, _busy_message(holder, holder_record, path)) from None
    except BaseException:
        os.close(fd)
        raise
    lock = DeviceLock(path, fd, device, {"pid": str(os.getpid()), "device": device, **about})
    with contextlib.suppress(OSError):  # a read-only lock file still locks
        _write(fd, lock.record)
    _HELD.append(lock)
    return lock


def note_run_directory(directory: Path | None) -> None:
    """Record a run's directory in every lock this process holds."""
    if directory is not None:
        for lock in _HELD:
            with contextlib.suppress(OSError):
                lock.note(directory=directory)


def lock_directory(holder: Holder, device: str) -> Path:
    """The directory of ``holder``'s locks, made if it is missing.

    Raises:
        DeviceBusy: it can be neither made nor replaced by the fallback.
    """
    configured = os.environ.get(LOCK_DIR_ENV)
    chosen = Path(configured) if configured else DEFAULT_DIRS[holder]
    try:
        chosen.mkdir(mode=0o770, parents=True, exist_ok=True)
        return chosen
    except OSError as error:
        if configured or chosen.exists():
            raise DeviceBusy(device, f"cannot take the device lock in {chosen}: "
                             f"{error.strerror or error} (${LOCK_DIR_ENV} names another "
                             "directory)") from None
    fallback = Path(f"/tmp/warden-locks-{os.getuid()}")
    fallback.mkdir(mode=0o700, exist_ok=True)
    return fallback


def _open(path: Path, device: str) -> int:
    try:
        return os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o660)
    except PermissionError:
        pass  # the service's lock file, readable by its group: an flock needs no write
    except OSError as error:
        raise DeviceBusy(device, f"cannot take the device lock {path}: "
                         f"{error.strerror or error}") from None
    try:
        return os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError as error:
        raise DeviceBusy(device, f"cannot take the device lock {path}: {error.strerror or error}"
                         f" (${LOCK_DIR_ENV} names another directory)") from None


def _file_name(holder: Holder, device: str) -> str:
    # Readable, and unique: two identities that read alike still get two files.
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", device).strip("_")[:SLUG_CHARS]
    return f"{holder}-{slug}-{hashlib.sha256(device.encode()).hexdigest()[:12]}.lock"


def _write(fd: int, record: dict[str, Any]) -> None:
    data = json.dumps(record).encode() + b"\n"
    os.ftruncate(fd, 0)
    os.pwrite(fd, data, 0)


def _read(fd: int) -> dict[str, Any]:
    try:
        record = json.loads(os.pread(fd, 4096, 0) or b"{}")
    except (OSError, ValueError):
        return {}
    return record if isinstance(record, dict) else {}


def _busy_message(holder: Holder, record: dict[str, Any], path: Path) -> str:
    who = "another safety monitor" if holder is Holder.MONITOR else "another warden"
    if "pid" not in record:  # it has the lock and has not written to it yet
        return f"in use by {who} that is starting (lock {path}); nothing was touched"
    parts = [f"pid {record['pid']}"]
    if record.get("command"):
        parts.append(f"`{record['command']}`")
    if record.get("run"):
        parts.append(f"run {record['run']}")
    if record.get("directory"):
        parts.append(f"run directory {record['directory']}")
    elif record.get("manifest"):
        parts.append(f"manifest {record['manifest']}")
    return (f"in use by {who}: {', '.join(parts)} (lock {path}); nothing was touched: stop "
            "that one first")


__all__ = ["DeviceBusy", "DeviceLock", "Holder", "acquire", "device_of", "holding",
           "note_run_directory"]
