"""Real file systems that fill up or turn read-only, for the tests of the run's record.

Each is a real mount (the tests run as root on Linux): a tmpfs of a few megabytes that fills
up, and an ext4 image on a loop device mounted ``errors=remount-ro`` that the kernel turns
read-only on request (``/sys/fs/ext4/<dev>/trigger_fs_error``), as it does after a real error,
or shuts down so that every write fails with EIO (``FS_IOC_SHUTDOWN``).
A mount that cannot be made fails the test with mount's own message: these tests never skip.
"""

from __future__ import annotations

import fcntl
import os
import struct
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def _run(*command: str) -> str:
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({result.returncode}): "
                           f"{result.stderr.strip()} -- these tests need root and mount(8)")
    return result.stdout


@contextmanager
def small_tmpfs(where: Path, size: str) -> Iterator[Path]:
    """A tmpfs of ``size`` (mount's syntax: ``3m``) mounted at ``where``."""
    where.mkdir(parents=True, exist_ok=True)
    _run("mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where))
    try:
        yield where
    finally:
        _run("umount", "-l", str(where))


@contextmanager
def read_only_tmpfs(where: Path) -> Iterator[Path]:
    """A tmpfs mounted read-only (nothing can be created in it)."""
    where.mkdir(parents=True, exist_ok=True)
    _run("mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(where))
    try:
        yield where
    finally:
        _run("umount", "-l", str(where))


_FS_IOC_SHUTDOWN = 0x8004587D  # _IOR('X', 125, __u32)
_SHUTDOWN_AFTER_SYNC = 0  # EXT4_GOING_FLAGS_DEFAULT: write everything back, then shut down


class Ext4:
    """An ext4 file system on a loop device that can be made to fail like a real one."""

    def __init__(self, mount_point: Path, device: str, image: Path) -> None:
        self.mount_point = mount_point
        self.device = device
        self.image = image

    def fail(self) -> None:
        """Report a file-system error: with ``errors=remount-ro`` the kernel makes it
        read-only at once, and every write from then on fails with EROFS."""
        name = Path(self.device).name
        Path(f"/sys/fs/ext4/{name}/trigger_fs_error").write_text("warden test\n")

    def fail_with_eio(self) -> None:
        """Shut the file system down (``FS_IOC_SHUTDOWN``, as xfstests' godown does), after
        writing back what it holds: from then on every write, allocation, truncation and sync
        fails with EIO, as on a disk that stopped answering."""
        fd = os.open(self.mount_point, os.O_RDONLY | os.O_DIRECTORY)
        try:
            fcntl.ioctl(fd, _FS_IOC_SHUTDOWN, struct.pack("I", _SHUTDOWN_AFTER_SYNC))
        finally:
            os.close(fd)

    def mounted_again(self) -> Path:
        """Unmount and mount the image again, read-only: what the disk holds, as anyone reading
        it after the run would find it (a shut-down file system answers reads with EIO)."""
        _run("umount", str(self.mount_point))
        _run("mount", "-o", "loop,ro", str(self.image), str(self.mount_point))
        return self.mount_point


@contextmanager
def ext4_image(where: Path, size_mb: int = 32) -> Iterator[Ext4]:
    """An ext4 image file mounted at ``where / "mnt"`` through a loop device."""
    image, mount_point = where / "ext4.img", where / "mnt"
    mount_point.mkdir(parents=True, exist_ok=True)
    with image.open("wb") as file:
        file.truncate(size_mb << 20)
    _run("mkfs.ext4", "-q", "-F", str(image))
    _run("mount", "-o", "loop,errors=remount-ro", str(image), str(mount_point))
    try:
        device = _run("findmnt", "-n", "-o", "SOURCE", str(mount_point)).strip()
        yield Ext4(mount_point, device, image)
    finally:
        _run("umount", "-l", str(mount_point))  # the loop device goes with it (autoclear)
