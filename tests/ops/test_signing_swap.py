"""A manifest replaced while it is being verified: what ``verify`` returns is the bytes the
signature covers, never a second read of the path (issue 15, item 14: returning a re-read let a
file swapped during ``verify`` pass as verified).

The path is a named pipe fed by a writer thread: the first open reads the signed manifest, any
later open reads a different manifest, so a second read of the path is seen, not guessed
(Linux: the thread tells one read from the next by the reader's descriptors in /proc).
"""

from __future__ import annotations

import array
import errno
import fcntl
import os
import shutil
import termios
import threading
import time
from pathlib import Path

from kernel.signing import generate_keypair, sign, signature_path, verify

ROOT = Path(__file__).resolve().parents[2]
SIM_MANIFEST = ROOT / "manifests" / "sim-ur5e.toml"
SWAPPED = b'# not the manifest that was signed\n[cell]\nname = "swapped"\n'
PATIENCE_S = 10.0


class PipeFeeder(threading.Thread):
    """Writes ``first`` to the first reader of ``pipe`` and ``later`` to every reader after it,
    until :meth:`stop`."""

    def __init__(self, pipe: Path, first: bytes, later: bytes) -> None:
        super().__init__(daemon=True)
        self.pipe, self.first, self.later = pipe, first, later
        self.done = threading.Event()
        self.reads = 0

    def run(self) -> None:
        deadline = time.monotonic() + PATIENCE_S
        while not self.done.is_set() and time.monotonic() < deadline:
            try:  # succeeds only while a reader has the pipe open
                fd = os.open(self.pipe, os.O_WRONLY | os.O_NONBLOCK)
            except OSError as error:
                if error.errno != errno.ENXIO:
                    raise
                time.sleep(0.001)
                continue
            try:
                os.set_blocking(fd, True)
                os.write(fd, self.first if self.reads == 0 else self.later)
                self.reads += 1
                _until_drained(fd)
            finally:
                os.close(fd)
            self._until_the_reader_closes()

    def _until_the_reader_closes(self) -> None:
        """The reader is this process: wait until none of its descriptors is the pipe, so that
        the next open is a new read, not the rest of this one."""
        deadline = time.monotonic() + PATIENCE_S
        while _open_here(self.pipe) and time.monotonic() < deadline:
            time.sleep(0.001)

    def stop(self) -> None:
        self.done.set()
        self.join(PATIENCE_S)


def _until_drained(fd: int) -> None:
    """Wait until the reader has taken every byte written: until then its open may not have
    returned yet (no descriptor in /proc to wait on), and a next open would succeed on the same
    read and append the later bytes to it (seen on a loaded host: the verified read was the
    signed manifest followed by the swapped one)."""
    deadline = time.monotonic() + PATIENCE_S
    waiting = array.array("i", [1])
    while time.monotonic() < deadline:
        fcntl.ioctl(fd, termios.FIONREAD, waiting)
        if waiting[0] == 0:
            return
        time.sleep(0.001)


def _open_here(path: Path) -> bool:
    for fd in os.listdir("/proc/self/fd"):
        try:
            if os.readlink(f"/proc/self/fd/{fd}") == str(path):
                return True
        except OSError:  # closed since it was listed
            continue
    return False


def test_verify_returns_the_bytes_it_verified_not_a_second_read(tmp_path: Path) -> None:
    keys = tmp_path / "trusted"
    keys.mkdir()
    generate_keypair(tmp_path / "signer.key", keys / "signer.pub")
    signed = tmp_path / "signed.toml"
    shutil.copyfile(SIM_MANIFEST, signed)
    sign(signed, tmp_path / "signer.key")
    pipe = tmp_path / "cell.toml"
    os.mkfifo(pipe)
    shutil.copyfile(signature_path(signed), signature_path(pipe))
    feeder = PipeFeeder(pipe, signed.read_bytes(), SWAPPED)
    feeder.start()
    try:
        verified = verify(pipe, keys)
    finally:
        feeder.stop()
    assert verified.content == signed.read_bytes()
    assert feeder.reads == 1, "verify read the manifest more than once"
