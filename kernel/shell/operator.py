"""Operator authority from outside the process: a Unix socket in the service's runtime directory.

``warden operator status|takeover|release|accept-recovery|stop|reset`` (kernel/cli_operator.py)
connects to the socket a running ``warden run`` serves and sends one request, a JSON line
``{"command": ...}``; the answer is one JSON line. Who may command the arm is decided twice:
the socket file is ``0660`` and belongs to the configured group (the file system refuses
everyone else), and the server reads the caller's credentials from the connection
(``SO_PEERCRED``) and refuses a caller who is neither root nor a member of that group. Every
command, granted or refused, is logged with the caller's uid, gid and pid; a granted command
reaches the core as an ``operator`` event carrying the uid, so the journal records who did it.

A takeover is answered once the first control tick owned by the human has run, with the
latency from the command's arrival to that tick (``latency_ms``): the human has the arm when the
answer says so, not before.
"""

from __future__ import annotations

import asyncio
import contextlib
import grp
import json
import os
import pwd
import socket
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import msgspec
import structlog

from assurance.fallback import Owner
from kernel.core.events import OperatorAction, OperatorEvent
from kernel.core.lines import Line, TickLine, encode
from kernel.shell.gateway import CoreGateway

log = structlog.get_logger("warden.operator")
_CREDENTIALS = struct.Struct("3i")  # struct ucred: pid, uid, gid
_MAX_REQUEST = 4096
_TAKEOVER_WAIT_S = 2.0
SOCKET_NAME = "operator.sock"
DEFAULT_RUNTIME_DIRECTORY = "/run/warden"


class OperatorCommand(StrEnum):
    STATUS = "status"
    TAKEOVER = "takeover"
    RELEASE = "release"
    ACCEPT_RECOVERY = "accept-recovery"
    STOP = "stop"
    RESET = "reset"
    CONFIRM = "confirm"
    """Starts a bounded trial that waits for a human (warden trial); nothing else."""


ACTIONS: dict[OperatorCommand, OperatorAction] = {
    OperatorCommand.TAKEOVER: OperatorAction.TAKEOVER,
    OperatorCommand.RELEASE: OperatorAction.RELEASE,
    OperatorCommand.ACCEPT_RECOVERY: OperatorAction.ACCEPT_RECOVERY,
    OperatorCommand.STOP: OperatorAction.ESTOP,
    OperatorCommand.RESET: OperatorAction.RESET,
}


@dataclass(frozen=True, slots=True)
class Caller:
    pid: int
    uid: int
    gid: int


@dataclass(slots=True)
class OperatorStats:
    granted: int = 0
    refused: int = 0
    takeover_latency_ms: list[float] = field(default_factory=list)


class OperatorServer:
    """Serves the operator socket for one run; ``status`` reads what the run reports."""

    def __init__(self, gateway: CoreGateway, path: Path, group: str,
                 status: Callable[[], dict[str, Any]]) -> None:
        self.gateway, self.path, self.group = gateway, path, group
        self.gid = grp.getgrnam(group).gr_gid
        self.status = status
        self.stats = OperatorStats()
        self._human_tick: asyncio.Event | None = None
        gateway.listeners.append(self._watch)

    async def run(self, started: Any = None) -> None:
        """Serve until cancelled; the socket file is removed when the server stops."""
        self._unlink_stale()
        server = await asyncio.start_unix_server(self._serve, path=str(self.path))
        try:
            os.chown(self.path, 0 if os.geteuid() == 0 else -1, self.gid)
            os.chmod(self.path, 0o660)
            log.info("operator socket", path=str(self.path), group=self.group)
            if started is not None:
                started()
            async with server:
                await server.serve_forever()
        finally:
            server.close()
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()

    def _unlink_stale(self) -> None:
        """A socket left by a run that died: nobody listens on it any more."""
        if self.path.is_socket():
            probe = socket.socket(socket.AF_UNIX)
            try:
                probe.connect(str(self.path))
            except OSError:
                self.path.unlink()
            else:
                raise OSError(f"{self.path}: another warden is serving this socket")
            finally:
                probe.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        received_ns = time.monotonic_ns()
        try:
            caller = _caller(writer)
            line = await asyncio.wait_for(reader.readline(), timeout=2.0)
            answer = await self._answer(caller, line[:_MAX_REQUEST], received_ns)
            writer.write(json.dumps(answer).encode() + b"\n")
            await writer.drain()
        except (TimeoutError, ConnectionError, OSError):
            pass  # a client that went away gets nothing more
        finally:
            writer.close()

    async def _answer(self, caller: Caller, line: bytes, received_ns: int) -> dict[str, Any]:
        try:
            request = json.loads(line)
            command = OperatorCommand(request["command"])
        except (ValueError, KeyError, TypeError):
            return {"ok": False, "error": f"not a request: expected one of "
                                          f"{', '.join(OperatorCommand)}"}
        if not self._allowed(caller):
            self.stats.refused += 1
            log.warning("operator command refused", command=command, uid=caller.uid,
                        gid=caller.gid, pid=caller.pid, reason=f"not in group {self.group}")
            return {"ok": False, "error": f"uid {caller.uid} is not in group {self.group}"}
        log.info("operator command", command=command, uid=caller.uid, gid=caller.gid,
                 pid=caller.pid)
        if command is OperatorCommand.STATUS:
            return {"ok": True, **self.status()}
        if command is OperatorCommand.CONFIRM:
            return {"ok": False, "error": "nothing to confirm: the run is already going"}
        self.stats.granted += 1
        return await self._command(command, caller, received_ns)

    async def _command(self, command: OperatorCommand, caller: Caller,
                       received_ns: int) -> dict[str, Any]:
        if command is OperatorCommand.TAKEOVER:
            self._human_tick = asyncio.Event()
        t = self.gateway.now_ns()
        step = self.gateway.feed(OperatorEvent(t=t, action=ACTIONS[command], uid=caller.uid))
        answer: dict[str, Any] = {"ok": True, "command": str(command),
                                  "lines": [_brief(line) for line in step.lines]}
        if command is OperatorCommand.TAKEOVER:
            answer.update(await self._takeover_latency(received_ns))
        answer.update(self.status())
        return answer

    async def _takeover_latency(self, received_ns: int) -> dict[str, Any]:
        event = self._human_tick
        try:
            if event is not None:
                await asyncio.wait_for(event.wait(), timeout=_TAKEOVER_WAIT_S)
        except TimeoutError:
            return {"took_over": False}
        finally:
            self._human_tick = None
        latency = (time.monotonic_ns() - received_ns) / 1e6
        self.stats.takeover_latency_ms.append(round(latency, 3))
        log.info("operator has the arm", latency_ms=round(latency, 3))
        return {"took_over": True, "latency_ms": round(latency, 3)}

    def _watch(self, lines: tuple[Line, ...]) -> None:
        event = self._human_tick
        if event is None:
            return
        if any(isinstance(line, TickLine) and line.owner == Owner.HUMAN for line in lines):
            event.set()

    def _allowed(self, caller: Caller) -> bool:
        return member(caller, self.gid)


def member(caller: Caller, gid: int) -> bool:
    """Root, or in the group (as its primary group or a supplementary one)."""
    if caller.uid == 0 or caller.gid == gid:
        return True
    try:
        name = pwd.getpwuid(caller.uid).pw_name
    except KeyError:
        return False
    return gid in os.getgrouplist(name, caller.gid)


async def await_confirmation(path: Path, group: str, run: str, timeout_s: float) -> Caller:
    """Serve the operator socket until a member of ``group`` sends ``confirm`` (a bounded
    trial starts only then); anything else is answered and refused.

    Raises:
        TimeoutError: nobody confirmed within ``timeout_s``.
    """
    gid = grp.getgrnam(group).gr_gid
    confirmed: asyncio.Future[Caller] = asyncio.get_running_loop().create_future()

    async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            caller = _caller(writer)
            line = await asyncio.wait_for(reader.readline(), timeout=2.0)
            answer = _confirmation(caller, gid, group, line[:_MAX_REQUEST], run, confirmed)
            writer.write(json.dumps(answer).encode() + b"\n")
            await writer.drain()
        except (TimeoutError, ConnectionError, OSError):
            pass
        finally:
            writer.close()

    if path.is_socket():
        path.unlink()
    server = await asyncio.start_unix_server(serve, path=str(path))
    try:
        os.chown(path, 0 if os.geteuid() == 0 else -1, gid)
        os.chmod(path, 0o660)
        async with server:
            return await asyncio.wait_for(asyncio.shield(confirmed), timeout=timeout_s)
    finally:
        server.close()
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def _confirmation(caller: Caller, gid: int, group: str, line: bytes, run: str,
                  confirmed: asyncio.Future[Caller]) -> dict[str, Any]:
    try:
        command = OperatorCommand(json.loads(line)["command"])
    except (ValueError, KeyError, TypeError):
        return {"ok": False, "error": "not a request"}
    if not member(caller, gid):
        log.warning("trial confirmation refused", uid=caller.uid, gid=caller.gid,
                    pid=caller.pid, reason=f"not in group {group}")
        return {"ok": False, "error": f"uid {caller.uid} is not in group {group}"}
    if command is OperatorCommand.STATUS:
        return {"ok": True, "run": run, "mode": "awaiting confirmation"}
    if command is not OperatorCommand.CONFIRM:
        return {"ok": False, "error": f"the trial {run} has not started: confirm it first"}
    log.info("trial confirmed", run=run, uid=caller.uid, gid=caller.gid, pid=caller.pid)
    if not confirmed.done():
        confirmed.set_result(caller)
    return {"ok": True, "confirmed": run, "uid": caller.uid}


def _caller(writer: asyncio.StreamWriter) -> Caller:
    sock = writer.get_extra_info("socket")
    raw = sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _CREDENTIALS.size)
    pid, uid, gid = _CREDENTIALS.unpack(raw)
    return Caller(pid, uid, gid)


def _brief(line: Line) -> dict[str, Any]:
    """A decision-log line for the operator's screen (its JSON form)."""
    return msgspec.json.decode(encode(line))


def socket_path(configured: str) -> Path:
    """Where the operator socket is: as configured, else in the service's runtime directory
    (systemd's ``RUNTIME_DIRECTORY``), else ``/run/warden``."""
    if configured:
        return Path(configured)
    runtime = os.environ.get("RUNTIME_DIRECTORY", "").split(":")[0]
    return Path(runtime or DEFAULT_RUNTIME_DIRECTORY) / SOCKET_NAME
