"""A TCP listener that can refuse connections on demand, as a controller whose server is gone.

Each accepted connection is handed to ``handle(sock)`` on its own daemon thread. ``refuse()``
closes the listening socket before it returns, so a client that reconnects right after a fault
gets "connection refused" instead of a half-alive server (ur_rtde reconnects within milliseconds
on its own receive thread, and a refused connect is the one failure it handles cleanly).
"""

from __future__ import annotations

import contextlib
import select
import socket
import threading
import time
from collections.abc import Callable

POLL_S = 0.02


class Listener:
    def __init__(self, host: str, port: int, handle: Callable[[socket.socket], None],
                 name: str) -> None:
        self.host, self.port, self.name = host, port, name
        self._handle = handle
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None
        self._stopped = threading.Event()
        self._thread = threading.Thread(target=self._accept_loop, name=name, daemon=True)

    def start(self) -> Listener:
        """Bind now (so a taken address fails here, loudly) and start accepting."""
        self.resume()
        self._thread.start()
        return self

    def refuse(self) -> None:
        with self._lock:
            if self._sock is None:
                return
            # shutdown() takes the socket out of LISTEN at once. close() alone does not while
            # the accept thread's select() still holds the file: connections made in that
            # window would be accepted by the kernel and then reset.
            with contextlib.suppress(OSError):
                self._sock.shutdown(socket.SHUT_RDWR)
            self._sock.close()
            self._sock = None

    def resume(self) -> None:
        with self._lock:
            if self._sock is None:
                self._sock = _bind(self.host, self.port)

    def stop(self) -> None:
        self._stopped.set()
        self.refuse()

    def _accept_loop(self) -> None:
        while not self._stopped.is_set():
            with self._lock:
                listening = self._sock
            if listening is None:
                time.sleep(POLL_S)
                continue
            try:
                ready, _, _ = select.select([listening], [], [], POLL_S)
            except (OSError, ValueError):
                continue  # closed by refuse() while we waited
            if ready:
                self._accept(listening)

    def _accept(self, listening: socket.socket) -> None:
        with self._lock:
            if self._sock is not listening:
                return
            try:
                connection, _ = listening.accept()
            except OSError:  # BlockingIOError too: the client left between select and accept
                return
        connection.setblocking(True)
        threading.Thread(
            target=self._handle, args=(connection,), name=f"{self.name}-conn", daemon=True
        ).start()


def _bind(host: str, port: int) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    # Reuse lets a restarted emulator (or a resumed listener) bind while old connections
    # linger in TIME_WAIT; it does not let two live listeners share the address.
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    sock.listen(16)
    sock.setblocking(False)  # accept() under the lock must never wait
    return sock
