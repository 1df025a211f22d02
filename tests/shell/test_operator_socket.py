"""The operator socket in process: a real core behind a real Unix socket, clients over it.

The answer tells the truth (``ok`` only when the core granted the command, and why not
otherwise); the socket is bounded (line length, duplicate keys and unknown fields, idle
connections, connections per uid) and keeps serving the operators whatever a client does. The
whole-cell runs, and the CLI's exit codes, are in tests/cell/test_operator.py.
"""

from __future__ import annotations

import asyncio
import contextlib
import grp
import io
import json
import logging
import os
import pwd
import shutil
import socket
import tempfile
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import structlog

from kernel.cli_operator import send
from kernel.core.events import ControllerEvent, ControllerStatus
from kernel.core.runtime import Core
from kernel.shell.gateway import CoreGateway
from kernel.shell.logging import configure_logging
from kernel.shell.operator import OperatorServer
from kernel.shell.operator_socket import DEFAULT_LIMITS, SocketLimits
from kernel.shell.timer import VirtualClock
from tests.runtime.machine_setup import core_config

# Long enough that no connection of a test times out unless the test says so: an answer that
# arrives at all arrived before the idle timeout fired.
PATIENT = SocketLimits(idle_timeout_s=60.0)
CLIENT_TIMEOUT_S = 10.0


@dataclass
class Served:
    server: OperatorServer
    gateway: CoreGateway

    @property
    def path(self) -> str:
        return str(self.server.path)

    @property
    def mode(self) -> str:
        return str(self.gateway.core.status().mode)

    async def send(self, command: str) -> dict[str, Any]:
        return await asyncio.to_thread(send, self.path, command, CLIENT_TIMEOUT_S)

    async def raw(self, data: bytes) -> dict[str, Any]:
        """Send ``data`` as it is; the one answer line."""
        return await asyncio.to_thread(_exchange, self.path, data)

    async def held(self, uid: int, count: int) -> None:
        """Until the server holds ``count`` connections of ``uid`` (it accepts them in turn)."""
        async with asyncio.timeout(CLIENT_TIMEOUT_S):
            while self.server.socket.open_connections(uid) != count:
                await asyncio.sleep(0.01)


def _exchange(path: str, data: bytes) -> dict[str, Any]:
    with socket.socket(socket.AF_UNIX) as sock:
        sock.settimeout(CLIENT_TIMEOUT_S)
        sock.connect(path)
        sock.sendall(data)
        return _answer(sock)


def _answer(sock: socket.socket) -> dict[str, Any]:
    received = b""
    while not received.endswith(b"\n"):
        chunk = sock.recv(65536)
        assert chunk, f"the server closed without an answer (after {received!r})"
        received += chunk
    answer: dict[str, Any] = json.loads(received)
    return answer


def _still_open(sock: socket.socket) -> bool:
    """Neither answered nor closed by the server (nothing to read yet)."""
    try:
        sock.recv(1, socket.MSG_DONTWAIT | socket.MSG_PEEK)
    except BlockingIOError:
        return True
    return False


@pytest.fixture
def directory() -> Iterator[Path]:
    # A short path: a Unix socket's path is at most 107 bytes, and pytest's tmp_path is long.
    path = Path(tempfile.mkdtemp(prefix="warden-op-"))
    path.chmod(0o755)  # a user dropped to nobody must reach the socket inside
    yield path
    shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def log_lines() -> Iterator[io.StringIO]:
    stream = io.StringIO()
    configure_logging("INFO", stream)
    yield stream
    structlog.reset_defaults()


def _logged(stream: io.StringIO, event: str) -> list[dict[str, Any]]:
    lines = [json.loads(line) for line in stream.getvalue().splitlines()]
    return [line for line in lines if line["event"] == event]


@contextlib.asynccontextmanager
async def serving(directory: Path, limits: SocketLimits = DEFAULT_LIMITS) -> AsyncIterator[Served]:
    gateway = CoreGateway(Core(core_config()), VirtualClock())
    group = grp.getgrgid(os.getegid()).gr_name
    served = Served(OperatorServer(gateway, directory / "operator.sock", group,
                                   lambda: {"mode": str(gateway.core.status().mode)},
                                   limits), gateway)
    async with asyncio.TaskGroup() as tasks:
        ready = asyncio.Event()
        task = tasks.create_task(served.server.run(ready.set))
        await ready.wait()
        try:
            yield served
        finally:
            task.cancel()
    assert not served.server.path.exists()  # the socket file goes with the server


# --- the answer tells the truth ----------------------------------------------------------------


async def test_ok_only_when_the_core_grants_the_command(directory: Path,
                                                        log_lines: io.StringIO) -> None:
    async with serving(directory) as served:
        assert served.mode == "RUNNING"
        refused = await served.send("accept-recovery")
        assert refused["ok"] is False and refused["reason"] == "GUARD_FAILED"
        assert refused["error"] == "refused: nothing to recover from in RUNNING"
        assert [line["accepted"] for line in refused["lines"]] == [False]
        assert (await served.send("reset"))["error"] == "refused: no e-stop to reset in RUNNING"
        assert (await served.send("release"))["ok"] is False

        stopped = await served.send("stop")
        assert stopped["ok"] is True and stopped["mode"] == "E_STOP"
        refused = await served.send("accept-recovery")
        assert refused["ok"] is False and refused["mode"] == "E_STOP"
        assert refused["error"] == "refused: nothing to recover from in E_STOP"
        assert (await served.send("reset"))["mode"] == "SAFE_HOLD"
        recovered = await served.send("accept-recovery")
        assert recovered["ok"] is True and "error" not in recovered
        assert any(line.get("trigger") == "RECOVERY_ACCEPTED" for line in recovered["lines"])
    assert served.server.stats.refused == 4 and served.server.stats.granted == 3
    # The refusal's why is in the log, next to a bounded reason code.
    logged = _logged(log_lines, "operator command refused by the core")
    assert (logged[0]["reason"], logged[0]["detail"]) == (
        "GUARD_FAILED", "nothing to recover from in RUNNING")


async def test_recovery_from_a_controller_stop_waits_for_the_controller(directory: Path) -> None:
    async with serving(directory) as served:
        served.gateway.feed(ControllerEvent(t=served.gateway.now_ns(),
                                            status=ControllerStatus.FAULT))
        assert served.mode == "CONTROLLER_STOP"
        refused = await served.send("accept-recovery")
        assert refused["ok"] is False
        assert refused["error"] == "refused: controller has not reported ok"
        served.gateway.feed(ControllerEvent(t=served.gateway.now_ns(),
                                            status=ControllerStatus.OK))
        assert (await served.send("accept-recovery"))["ok"] is True


# --- the socket is bounded ---------------------------------------------------------------------


async def test_a_line_over_64_kib_is_answered_and_the_server_goes_on(
        directory: Path, caplog: pytest.LogCaptureFixture) -> None:
    async with serving(directory) as served:
        answer = await served.raw(b'{"command": "' + b"x" * 70_000 + b'"}\n')
        assert answer == {"ok": False, "error": "request longer than 4096 bytes: one JSON "
                                                "object on one line expected"}
        assert (await served.send("status"))["ok"] is True
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]  # no traceback


async def test_duplicate_keys_and_unknown_fields_are_refused(directory: Path) -> None:
    async with serving(directory) as served:
        twice = await served.raw(b'{"command": "status", "command": "stop"}\n')
        assert twice == {"ok": False, "error": "not a request: duplicate key 'command'"}
        unknown = await served.raw(b'{"command": "stop", "uid": 0}\n')
        assert unknown["ok"] is False
        assert unknown["error"].startswith("not a request: Object contains unknown field `uid`")
        assert served.mode == "RUNNING"  # neither reached the core
        assert (await served.raw(b"[1, 2]\n"))["error"].startswith("not a request")
        assert (await served.raw(b'{"command": "stop"}\n'))["mode"] == "E_STOP"


async def test_a_client_is_served_while_150_idle_connections_are_open(directory: Path) -> None:
    limits = SocketLimits(idle_timeout_s=PATIENT.idle_timeout_s, per_uid=200)
    async with serving(directory, limits) as served:
        idle: list[socket.socket] = []
        try:
            # A burst of connects while the loop runs nothing else (this coroutine does not
            # yield): the kernel queues them all, warden accepts none yet.
            for _ in range(151):
                sock = socket.socket(socket.AF_UNIX)
                idle.append(sock)
                sock.setblocking(False)
                sock.connect(served.path)  # EAGAIN once the listen backlog is full
            client = idle[-1]
            client.setblocking(True)
            client.settimeout(CLIENT_TIMEOUT_S)
            client.sendall(b'{"command": "status"}\n')
            answer = await asyncio.to_thread(_answer, client)
            assert answer["ok"] is True
            # Answered while every idle connection is still open: not because they timed out.
            assert all(_still_open(sock) for sock in idle[:-1])
            assert served.server.socket.open_connections(os.geteuid()) >= 150
        finally:
            for sock in idle:
                sock.close()


async def test_one_uid_holds_at_most_its_bound_of_connections(directory: Path,
                                                            log_lines: io.StringIO) -> None:
    limits = SocketLimits(idle_timeout_s=PATIENT.idle_timeout_s, per_uid=4)
    uid = os.geteuid()
    async with serving(directory, limits) as served:
        idle = [socket.socket(socket.AF_UNIX) for _ in range(4)]
        try:
            for sock in idle:
                sock.connect(served.path)
            await served.held(uid, 4)
            for _ in range(3):
                turned_away = await served.send("status")
                assert turned_away == {"ok": False, "error": f"uid {uid} has 4 connections "
                                       "open to this socket (the limit): close one and retry"}
            assert all(_still_open(sock) for sock in idle)
            idle.pop().close()
            await served.held(uid, 3)
            assert (await served.send("status"))["ok"] is True
        finally:
            for sock in idle:
                sock.close()
    assert len(_logged(log_lines, "operator connections at the limit")) == 1  # not 3


async def test_a_silent_connection_is_answered_and_closed_after_the_idle_timeout(
        directory: Path) -> None:
    async with serving(directory, SocketLimits(idle_timeout_s=0.2)) as served:
        with socket.socket(socket.AF_UNIX) as sock:
            sock.settimeout(CLIENT_TIMEOUT_S)
            sock.connect(served.path)
            answer = await asyncio.to_thread(_answer, sock)
            assert answer == {"ok": False, "error": "no request line within 0.2 s"}
            assert await asyncio.to_thread(sock.recv, 1) == b""  # and closed
        await served.held(os.geteuid(), 0)


# --- other users (root only: the test drops a child process to nobody) --------------------------

as_root = pytest.mark.skipif(os.geteuid() != 0, reason="needs root to act as another user")


def _as_nobody(path: str, request: bytes, hold: int = 0) -> tuple[int, int, int]:
    """Fork a child that drops to nobody, opens ``hold`` idle connections to ``path``, sends
    ``request`` on one more and reports its answer; it keeps the idle ones until told to go.
    The child's pid, the pipe its report comes on, the pipe that tells it to go."""
    nobody = pwd.getpwnam("nobody")
    report_r, report_w = os.pipe()
    go_r, go_w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        try:
            os.close(go_w)
            os.close(report_r)
            os.setgroups([])
            os.setgid(nobody.pw_gid)
            os.setuid(nobody.pw_uid)
            held = []
            for _ in range(hold):
                sock = socket.socket(socket.AF_UNIX)
                sock.setblocking(False)
                with contextlib.suppress(BlockingIOError):
                    sock.connect(path)
                    held.append(sock)
            outcome: dict[str, Any] = send(path, request.decode().strip(), CLIENT_TIMEOUT_S)
        except OSError as error:
            outcome = {"error": type(error).__name__}
        os.write(report_w, json.dumps(outcome).encode() + b"\n")
        os.read(go_r, 1)
        os._exit(0)
    os.close(report_w)
    os.close(go_r)
    return pid, report_r, go_w


def _report(read: int) -> dict[str, Any]:
    with os.fdopen(read) as stream:
        report: dict[str, Any] = json.loads(stream.readline())
    return report


@as_root
async def test_a_user_outside_the_group_is_refused_and_the_log_says_why(
        directory: Path, log_lines: io.StringIO) -> None:
    async with serving(directory) as served:
        served.server.path.chmod(0o666)  # loosened by mistake: the server still checks
        pid, report, go = _as_nobody(served.path, b"stop")
        try:
            answer = await asyncio.to_thread(_report, report)
        finally:
            os.close(go)
            await asyncio.to_thread(os.waitpid, pid, 0)
        assert answer == {"ok": False, "error": f"uid {pwd.getpwnam('nobody').pw_uid} is not "
                                                "in group root"}
        assert served.mode == "RUNNING"
    (refused,) = _logged(log_lines, "operator command refused")
    assert (refused["reason"], refused["detail"]) == ("NO_AUTHORITY", "not in group root")


@as_root
async def test_another_user_flooding_the_socket_does_not_keep_root_out(directory: Path) -> None:
    nobody = pwd.getpwnam("nobody").pw_uid
    async with serving(directory, PATIENT) as served:
        served.server.path.chmod(0o666)
        pid, report, go = _as_nobody(served.path, b"status", hold=150)
        try:
            flooded = await asyncio.to_thread(_report, report)  # its connections are open
            assert flooded["ok"] is False  # past its own bound, or not in the group
            answer = await served.send("status")
            assert answer["ok"] is True
            assert served.server.socket.open_connections(nobody) <= PATIENT.per_uid
        finally:
            os.close(go)
            await asyncio.to_thread(os.waitpid, pid, 0)
