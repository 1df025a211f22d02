"""``warden safety status``: "are you alive, connected, and watching?", asked of the live monitor.

The monitor serves a Unix stream socket (``[safety] status_socket``, 0660 to the configured
group). A client connects, sends one JSON line with a random nonce, and gets one JSON line back,
computed at that moment from the monitor's own state: when it last completed a check, whether its
device connection and stop path answer, the heartbeat it sees, the breaches and stops. Nothing
is read from a file: a monitor that is gone leaves nobody to answer (the connection is refused),
a hung one answers nothing within the client's deadline, and the nonce must come back, so an
answer cannot be a replay. One connect, one line each way: cheap enough for a launcher to ask
before every trial.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import socket
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import structlog

log = structlog.get_logger("warden.safety")
_MAX_REQUEST = 1024
_SERVE_TIMEOUT_S = 1.0


class StatusServer:
    """Serves status on its own thread; :meth:`close` stops it and removes the socket."""

    def __init__(self, path: Path, gid: int, status: Callable[[], dict[str, Any]]) -> None:
        self.path, self.status = path, status
        _unlink_stale(path)
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        try:
            self._sock.bind(str(path))
            os.chown(path, -1, gid)
            os.chmod(path, 0o660)
            self._sock.listen(8)
        except OSError:
            self._sock.close()
            raise
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="safety-status", daemon=True)

    def start(self) -> StatusServer:
        self._thread.start()
        return self

    def close(self) -> None:
        self._closed.set()
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()
        self._thread.join(timeout=2.0)
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

    def _serve(self) -> None:
        while not self._closed.is_set():
            try:
                connection, _ = self._sock.accept()
            except OSError:
                return  # closed
            with connection:
                self._answer(connection)

    def _answer(self, connection: socket.socket) -> None:
        try:
            connection.settimeout(_SERVE_TIMEOUT_S)
            line = connection.makefile("rb").readline(_MAX_REQUEST)
            request = json.loads(line)
            nonce = str(request["nonce"])[:64] if isinstance(request, dict) else ""
            answer = {**self.status(), "nonce": nonce, "pid": os.getpid()}
            connection.sendall(json.dumps(answer).encode() + b"\n")
        except (OSError, ValueError, KeyError):
            pass  # a client that sent nothing sensible, or left, gets nothing more


def ask(path: Path, timeout_s: float) -> dict[str, Any]:
    """The live monitor's answer.

    Raises:
        OSError: nobody serves ``path`` (PermissionError: not in the socket's group), or no
            answer within ``timeout_s``.
        ValueError: the answer is not this monitor's: not JSON, or the nonce did not come back.
    """
    nonce = secrets.token_hex(16)
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout_s)
        sock.connect(str(path))
        sock.sendall(json.dumps({"nonce": nonce}).encode() + b"\n")
        line = sock.makefile("rb").readline(1 << 20)
    answer = json.loads(line)
    if not isinstance(answer, dict) or answer.get("nonce") != nonce:
        raise ValueError("the answer did not carry this request's nonce")
    return answer


def socket_problem(path: Path, error: OSError) -> str:
    """Why the socket at ``path`` cannot be served or asked, naming the path and, when it is
    the reason, its missing directory (an ``OSError``'s own text, "[Errno 2] No such file or
    directory", names neither)."""
    if isinstance(error, FileNotFoundError):
        if not path.parent.is_dir():
            return f"{path}: its directory {path.parent} does not exist"
        return f"{path}: no such socket"
    if error.strerror:
        return f"{path}: {error.strerror[0].lower()}{error.strerror[1:]}"
    return str(error) if str(path) in str(error) else f"{path}: {error}"


def _unlink_stale(path: Path) -> None:
    """Raises:
        OSError: another monitor serves ``path``.
    """
    if not path.is_socket():
        return
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.connect(str(path))
    except OSError:
        path.unlink()
    else:
        raise OSError(f"{path}: another safety monitor serves this socket")
    finally:
        probe.close()
