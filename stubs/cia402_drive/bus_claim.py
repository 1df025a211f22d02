"""One emulated drive set per simulated bus: a ``udp_multicast`` bus (group and port) is
claimed with an flock(2) on a host-wide lock file before the emulator opens it.

Two emulators on one group and port are two sets of drives with the same node ids on one bus:
each answers the other's SDO requests and the transfers break. The second one refuses to start
instead, naming the first one's pid. The kernel drops the claim when its holder exits, however
it exits.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
from pathlib import Path

CLAIMS = Path(tempfile.gettempdir()) / "cia402-emulator-buses"


class BusInUse(RuntimeError):
    """Another emulator runs drives on this bus."""


class BusClaim:
    def __init__(self, group: str, port: int) -> None:
        CLAIMS.mkdir(exist_ok=True)
        with contextlib.suppress(OSError):  # shared by every user's emulators, like /tmp
            CLAIMS.chmod(0o1777)
        path = CLAIMS / f"udp-{group}-{port}.lock"
        self._fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(self._fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(self._fd)
            raise BusInUse(f"udp_multicast bus {group} port {port} already has emulated drives "
                           f"(emulator pid {holder}, lock {path}); pick another --channel or "
                           "--port") from None
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, f"{os.getpid()}\n".encode(), 0)

    def release(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
