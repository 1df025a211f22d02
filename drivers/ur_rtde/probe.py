"""Pre-flight check of a UR controller, in plain Python sockets with deadlines.

Why before ur_rtde: its constructors hold the GIL while they connect, wait for replies and wait
for the first data package, some of that without any timeout. A wrong host, a non-UR server on
port 30004 or a stalled controller would freeze the whole process, event loop included. Here
the same questions are asked with a deadline on each, so the driver can refuse with a message
that says what to check; only then is the library let in.
"""

from __future__ import annotations

import socket
import struct
import time

from drivers.base import DriverInitError

RTDE_PORT, DASHBOARD_PORT, SCRIPT_PORT = 30004, 29999, 30003
HEADER = struct.Struct(">HB")
REQUEST_PROTOCOL_VERSION, GET_URCONTROL_VERSION = ord("V"), ord("v")
SETUP_OUTPUTS, START, PAUSE, DATA_PACKAGE, TEXT_MESSAGE = (ord(c) for c in "OSPUM")
PROTOCOL_VERSION = 2


class ControllerUnreachable(DriverInitError):
    """Nothing, or nothing that speaks UR, answers at the host: worth another attempt."""


def probe_controller(device: str, host: str, timeout_s: float) -> tuple[int, int, int, int]:
    """Check the three ports ur_rtde needs and that RTDE streams; return the URControl version."""
    _expect_dashboard(device, host, timeout_s)
    _connect(device, host, SCRIPT_PORT, "script port", timeout_s).close()
    with _connect(device, host, RTDE_PORT, "RTDE server", timeout_s) as sock:
        try:
            return _rtde_handshake(sock, timeout_s)
        except (OSError, ValueError, struct.error) as error:
            raise ControllerUnreachable(
                device, f"{host}:{RTDE_PORT} accepts connections but does not answer as a UR "
                f"RTDE server ({error}); check that `host` names a UR e-Series controller"
            ) from error


def _connect(device: str, host: str, port: int, what: str, timeout_s: float) -> socket.socket:
    try:
        sock = socket.create_connection((host, port), timeout=timeout_s)
    except OSError as error:
        raise ControllerUnreachable(
            device, f"cannot reach the UR {what} at {host}:{port} ({error}); check `host` in "
            "the manifest, the network, and that the controller is powered on"
        ) from error
    sock.settimeout(timeout_s)
    return sock


def _expect_dashboard(device: str, host: str, timeout_s: float) -> None:
    with _connect(device, host, DASHBOARD_PORT, "dashboard server", timeout_s) as sock:
        try:
            welcome = sock.makefile("rb").readline(256).decode(errors="replace")
        except OSError as error:
            welcome = f"no answer ({error})"
    if "Dashboard" not in welcome:
        raise ControllerUnreachable(
            device, f"{host}:{DASHBOARD_PORT} is not a UR dashboard server (it said "
            f"{welcome.strip()!r}); check that `host` names a UR controller"
        )


def _rtde_handshake(sock: socket.socket, timeout_s: float) -> tuple[int, int, int, int]:
    _send(sock, REQUEST_PROTOCOL_VERSION, struct.pack(">H", PROTOCOL_VERSION))
    _receive(sock, REQUEST_PROTOCOL_VERSION)
    _send(sock, GET_URCONTROL_VERSION, b"")
    version = struct.unpack(">4I", _receive(sock, GET_URCONTROL_VERSION)[:16])
    _send(sock, SETUP_OUTPUTS, struct.pack(">d", 125.0) + b"timestamp,")
    if not _receive(sock, SETUP_OUTPUTS)[0]:
        raise ValueError("it refused an output recipe of just 'timestamp'")
    _send(sock, START, b"")
    if not _receive(sock, START)[0]:
        raise ValueError("it refused to start data synchronisation")
    _wait_for_data(sock, timeout_s)
    _send(sock, PAUSE, b"")
    return version  # type: ignore[return-value]


def _wait_for_data(sock: socket.socket, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if _read_message(sock)[0] == DATA_PACKAGE:
            return
    raise ValueError(f"the data stream did not start within {timeout_s} s (stalled controller?)")


def _send(sock: socket.socket, kind: int, payload: bytes) -> None:
    sock.sendall(HEADER.pack(HEADER.size + len(payload), kind) + payload)


def _receive(sock: socket.socket, kind: int) -> bytes:
    """The payload of the next reply of ``kind``; text messages in between are skipped."""
    while True:
        got, payload = _read_message(sock)
        if got == kind:
            return payload
        if got != TEXT_MESSAGE:
            raise ValueError(f"expected message {chr(kind)!r}, got {got}")


def _read_message(sock: socket.socket) -> tuple[int, bytes]:
    size, kind = HEADER.unpack(_read_exactly(sock, HEADER.size))
    if size < HEADER.size:
        raise ValueError(f"message size {size} is shorter than its header")
    return kind, _read_exactly(sock, size - HEADER.size)


def _read_exactly(sock: socket.socket, count: int) -> bytes:
    data = b""
    while len(data) < count:
        chunk = sock.recv(count - len(data))
        if not chunk:
            raise ConnectionError("connection closed")
        data += chunk
    return data
