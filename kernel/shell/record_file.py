"""One file of a run's record (``journal.jsonl``, ``decisions.jsonl``): whole lines, appended,
with disk space reserved ahead of them.

Why the files are written this way (docs/operations.md, "Journals and replay"):

- **A cut is the only damage a kill can do.** The file is opened ``O_APPEND`` and written only
  by the recorder's writer thread, with ``write(2)`` on the descriptor (no user-space buffer
  that could be flushed half-way), each call carrying whole lines only. A process killed at
  any instant leaves the file ending at a line boundary or inside its last line; nothing
  before that line can be damaged. A write that fails part-way is cut back to the last whole
  line (``ftruncate``) before anything else is appended, so a line written later is never
  glued to a broken one. ``warden replay`` reads a cut last line as the end of the record.
- **A full disk still lets the run say why it stopped.** Before each batch the file's blocks
  are allocated for the batch *and* :data:`RESERVE_BYTES` beyond it (``fallocate`` with
  ``FALLOC_FL_KEEP_SIZE``: the size does not change, so a reader never sees zeros). When the
  allocation fails, nothing of that batch is written and the reserve is still there: the
  recorder writes the rest of the run (the failure, the core's stop, the last ticks) into it
  when the run ends. At close the unused reserve is given back (``ftruncate`` to the size).
  A file system that cannot preallocate (``EOPNOTSUPP``) is written without a reserve.
- **What reaches the disk when.** Every batch is handed to the kernel as soon as the writer
  thread has it (every ``flush_interval_s``, 50 ms); nothing is fsynced during the run, so a
  kill of the process loses only what had not been handed over yet, and a power cut also what
  the kernel had not written back. ``close`` calls ``fdatasync`` once.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
from pathlib import Path

from kernel.core.events import RecorderFault

RESERVE_BYTES = 1 << 20
"""Space kept allocated beyond the written end of each file: room for the rest of a run
that ended because the disk filled (the 50 ms batch that did not fit, the failure, the
stop and the last ticks: some 50 kB on the simulated cell)."""

_FALLOC_FL_KEEP_SIZE = 0x01
_NO_PREALLOCATION = frozenset({errno.EOPNOTSUPP, errno.ENOSYS})
_libc = ctypes.CDLL(None, use_errno=True)
_libc.fallocate.argtypes = (ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64)
_libc.fallocate.restype = ctypes.c_int


def _fallocate(fd: int, mode: int, offset: int, length: int) -> None:
    """Linux ``fallocate(2)`` (os.posix_fallocate cannot keep the size).

    Raises:
        OSError: as the system call failed (ENOSPC, EOPNOTSUPP, ...).
    """
    if _libc.fallocate(fd, mode, offset, length) != 0:
        code = ctypes.get_errno()
        raise OSError(code, os.strerror(code))


def fault_of(error: OSError) -> RecorderFault:
    """What a write error means for the core."""
    if error.errno in (errno.ENOSPC, errno.EDQUOT):
        return RecorderFault.NO_SPACE
    if error.errno == errno.EROFS:
        return RecorderFault.READ_ONLY
    return RecorderFault.IO_ERROR


class RecordFile:
    """A new file, appended in whole lines with :data:`RESERVE_BYTES` allocated beyond them.

    Raises (constructor):
        OSError: the file cannot be created, or the reserve cannot be allocated.
    """

    def __init__(self, path: Path, reserve_bytes: int = RESERVE_BYTES) -> None:
        self.path = path
        self.reserve_bytes = reserve_bytes
        self.preallocates = True
        self.end = 0
        """Bytes written, all of them whole lines."""
        self.lines = 0
        """Lines written."""
        self.last_line = b""
        """The last line written (without its newline): where the file ends."""
        self.sync_error: str | None = None
        """Why the data could not be written back to the disk at close, if it could not."""
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND
                           | os.O_CLOEXEC, 0o644)
        try:
            self.reserve_for(0)
        except OSError:
            os.close(self._fd)
            raise

    @property
    def reserved(self) -> int:
        """Bytes certainly writable beyond the end without asking the file system for more."""
        return self.reserve_bytes if self.preallocates else 0

    def reserve_for(self, size: int) -> None:
        """Allocate ``size`` more bytes and the reserve beyond them.

        Raises:
            OSError: the file system cannot hold them (ENOSPC, EDQUOT, EIO, EROFS, ...); the
                reserve allocated before is still there.
        """
        if not self.preallocates:
            return
        try:
            _fallocate(self._fd, _FALLOC_FL_KEEP_SIZE, self.end, size + self.reserve_bytes)
        except OSError as error:
            if error.errno not in _NO_PREALLOCATION:
                raise
            self.preallocates = False  # written as any file: no reserve on this file system

    def append(self, data: bytes) -> None:
        """Write ``data`` (whole lines) at the end.

        Raises:
            OSError: the write failed; the file was cut back to its last whole line (if the
                file system still allowed that).
        """
        view = memoryview(data)
        written = 0
        try:
            while written < len(data):  # a regular file takes it all unless something fails
                written += self._write(view[written:])
        except OSError:
            self._cut_back()
            raise
        self.end += len(data)
        self.lines += data.count(b"\n")
        body = data.rstrip(b"\n")
        self.last_line = body[body.rfind(b"\n") + 1:]

    def _write(self, data: memoryview) -> int:
        """One ``write(2)``: the boundary where a disk that fails part-way can be injected."""
        return os.write(self._fd, data)

    def close(self) -> None:
        """Give the unused reserve back, write the data back to the disk, close. Safe to call
        twice.

        Raises:
            OSError: the data could not be synced (the descriptor is closed regardless).
        """
        if self._fd < 0:
            return
        try:
            if self.preallocates:
                # Truncating to the same size frees the blocks beyond it (ext4 and tmpfs; a
                # punched hole beyond the end is ignored by ext4). A reserve kept would be
                # disk space wasted, not a record damaged.
                with contextlib.suppress(OSError):
                    os.ftruncate(self._fd, self.end)
            os.fdatasync(self._fd)
        except OSError as error:
            self.sync_error = error.strerror or str(error)
            raise
        finally:
            fd, self._fd = self._fd, -1
            os.close(fd)

    def _cut_back(self) -> None:
        # If even this fails, the file ends inside its last line: a replay stops before it.
        with contextlib.suppress(OSError):
            os.ftruncate(self._fd, self.end)


def open_run_files(directory: Path, name: str,
                   reserve_bytes: int = RESERVE_BYTES) -> tuple[Path, RecordFile, RecordFile]:
    """A fresh run directory with ``journal.jsonl`` and ``decisions.jsonl``.

    Raises:
        OSError: the directory or a file cannot be made, or the reserve not allocated.
    """
    directory.mkdir(parents=True, exist_ok=True)
    index = 1 + max((int(p.name.rsplit("-", 1)[-1]) for p in directory.glob(f"{name}-*")
                     if p.name.rsplit("-", 1)[-1].isdigit()), default=0)
    run_dir = directory / f"{name}-{index:04d}"
    run_dir.mkdir()
    journal = RecordFile(run_dir / "journal.jsonl", reserve_bytes)
    try:
        decisions = RecordFile(run_dir / "decisions.jsonl", reserve_bytes)
    except OSError:
        journal.close()
        raise
    return run_dir, journal, decisions


def journal_directory_problem(directory: Path) -> str | None:
    """Why run journals cannot be kept in ``directory``, or None if they can: made if missing,
    then a probe file created, written, given both files' reserves, and removed. Catches
    /dev/null, /proc, /sys, a read-only file system, a missing permission, a disk too full to
    reserve the space a failing run needs to say why it stopped."""
    if directory.exists() and not directory.is_dir():
        return "not a directory"
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        return f"cannot make the directory: {error.strerror or error}"
    probe = directory / f".warden-probe-{os.getpid()}"
    try:
        probe.unlink(missing_ok=True)  # left by a process of the same id that was killed
        record = RecordFile(probe, 2 * RESERVE_BYTES)  # a journal's and a decision log's
        try:
            record.append(b"\n")
        finally:
            record.close()
    except OSError as error:
        return f"cannot write a file there: {error.strerror or error}"
    finally:
        with contextlib.suppress(OSError):  # it could not even be created
            probe.unlink(missing_ok=True)
    return None
