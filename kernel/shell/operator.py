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
import grp
import os
import pwd
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import msgspec
import structlog

from assurance.fallback import Owner
from assurance.reasons import ReasonCode
from kernel.core.events import OperatorAction, OperatorEvent
from kernel.core.lines import Line, Machine, TickLine, TransitionLine, encode
from kernel.shell.gateway import CoreGateway
from kernel.shell.operator_socket import (
    DEFAULT_LIMITS,
    Answer,
    Caller,
    DuplicateKey,
    LineServer,
    SocketLimits,
    reject_duplicate_keys,
)

log = structlog.get_logger("warden.operator")
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


class Request(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One line a client sends: ``{"command": ...}`` and nothing else."""

    command: OperatorCommand


_REQUEST = msgspec.json.Decoder(Request)


def parse_request(line: bytes) -> Request | str:
    """The request on ``line``, or why it is not one (a duplicate key, an unknown field, an
    unknown command, not JSON)."""
    try:
        reject_duplicate_keys(line)
        return _REQUEST.decode(line)
    except DuplicateKey as error:
        return f"not a request: {error}"
    except msgspec.ValidationError as error:
        return f"not a request: {error} (commands: {', '.join(OperatorCommand)})"
    except (ValueError, msgspec.DecodeError):
        return (f"not a request: one JSON object per line expected, {{\"command\": C}} with C "
                f"one of {', '.join(OperatorCommand)}")


@dataclass(slots=True)
class OperatorStats:
    granted: int = 0
    refused: int = 0
    takeover_latency_ms: list[float] = field(default_factory=list)


class OperatorServer:
    """Serves the operator socket for one run; ``status`` reads what the run reports."""

    def __init__(self, gateway: CoreGateway, path: Path, group: str,
                 status: Callable[[], dict[str, Any]],
                 limits: SocketLimits = DEFAULT_LIMITS) -> None:
        self.gateway, self.path, self.group = gateway, path, group
        self.gid = grp.getgrnam(group).gr_gid
        self.status = status
        self.stats = OperatorStats()
        self.socket = LineServer(path, self.gid, self._answer, limits)
        self._human_tick: asyncio.Event | None = None
        gateway.listeners.append(self._watch)

    async def run(self, started: Callable[[], None] | None = None) -> None:
        """Serve until cancelled; the socket file is removed when the server stops."""
        _unlink_stale(self.path)
        self.socket.open()
        log.info("operator socket", path=str(self.path), group=self.group)
        await self.socket.serve(started)

    async def _answer(self, caller: Caller, line: bytes, received_ns: int) -> Answer:
        request = parse_request(line)
        if isinstance(request, str):
            return {"ok": False, "error": request}
        command = request.command
        if not member(caller, self.gid):
            self.stats.refused += 1
            log.warning("operator command refused", command=command, uid=caller.uid,
                        gid=caller.gid, pid=caller.pid, reason=ReasonCode.NO_AUTHORITY,
                        detail=f"not in group {self.group}")
            return {"ok": False, "error": f"uid {caller.uid} is not in group {self.group}"}
        log.info("operator command", command=command, uid=caller.uid, gid=caller.gid,
                 pid=caller.pid)
        if command is OperatorCommand.STATUS:
            return {"ok": True, **self.status()}
        if command is OperatorCommand.CONFIRM:
            return {"ok": False, "error": "nothing to confirm: the run is already going"}
        if self.gateway.closed:
            return {"ok": False, "error": "the run is over: nothing more is decided",
                    **self.status()}
        return await self._command(command, caller, received_ns)

    async def _command(self, command: OperatorCommand, caller: Caller,
                       received_ns: int) -> Answer:
        """Feed the command to the core; the answer is ``ok`` only if the core granted it."""
        t = self.gateway.now_ns()
        step = self.gateway.feed(OperatorEvent(t=t, action=ACTIONS[command], uid=caller.uid))
        refusal = _refusal(step.lines)
        answer: Answer = {"ok": refusal is None, "command": str(command),
                          "lines": [_brief(line) for line in step.lines]}
        if refusal is not None:
            self.stats.refused += 1
            log.warning("operator command refused by the core", command=command,
                        uid=caller.uid, reason=refusal.trigger, detail=refusal.detail)
            answer.update(error=f"refused: {refusal.detail}", reason=str(refusal.trigger))
        else:
            self.stats.granted += 1
            if command is OperatorCommand.TAKEOVER:
                answer.update(await self._takeover_latency(received_ns))
        answer.update(self.status())
        return answer

    async def _takeover_latency(self, received_ns: int) -> dict[str, Any]:
        # Armed after the core granted the takeover: the human's first tick comes later, from
        # the control loop, never from the step that granted it.
        event = self._human_tick = asyncio.Event()
        try:
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


def _refusal(lines: tuple[Line, ...]) -> TransitionLine | None:
    """The core's refusal of an operator command: the fallback machine's transition line that
    was not accepted (its ``detail`` says why), or None when the command was granted."""
    return next((line for line in lines if isinstance(line, TransitionLine)
                 and line.machine is Machine.FALLBACK and not line.accepted), None)


def _unlink_stale(path: Path) -> None:
    """A socket left by a run that died: nobody listens on it any more.

    Raises:
        OSError: another process serves it.
    """
    if path.is_socket():
        probe = socket.socket(socket.AF_UNIX)
        try:
            probe.connect(str(path))
        except OSError:
            path.unlink()
        else:
            raise OSError(f"{path}: another warden is serving this socket")
        finally:
            probe.close()


def member(caller: Caller, gid: int) -> bool:
    """Root, or in the group (as its primary group or a supplementary one)."""
    if caller.uid == 0 or caller.gid == gid:
        return True
    try:
        name = pwd.getpwuid(caller.uid).pw_name
    except KeyError:
        return False
    return gid in os.getgrouplist(name, caller.gid)


async def await_confirmation(path: Path, group: str, run: str, timeout_s: float,
                             limits: SocketLimits = DEFAULT_LIMITS) -> Caller:
    """Serve the operator socket until a member of ``group`` sends ``confirm`` (a bounded
    trial starts only then); anything else is answered and refused.

    Raises:
        TimeoutError: nobody confirmed within ``timeout_s``.
    """
    gid = grp.getgrnam(group).gr_gid
    confirmed: asyncio.Future[Caller] = asyncio.get_running_loop().create_future()

    async def answer(caller: Caller, line: bytes, received_ns: int) -> Answer:
        return _confirmation(caller, gid, group, line, run, confirmed)

    if path.is_socket():
        path.unlink()
    server = LineServer(path, gid, answer, limits)
    server.open()
    try:
        async with asyncio.TaskGroup() as tasks:
            serving = tasks.create_task(server.serve())
            await asyncio.wait([confirmed], timeout=timeout_s)
            serving.cancel()
    finally:
        server.close()  # also when the serving task was cancelled before it started
    if not confirmed.done():
        raise TimeoutError(f"no confirmation within {timeout_s:g} s")
    return confirmed.result()


def _confirmation(caller: Caller, gid: int, group: str, line: bytes, run: str,
                  confirmed: asyncio.Future[Caller]) -> Answer:
    request = parse_request(line)
    if isinstance(request, str):
        return {"ok": False, "error": request}
    if not member(caller, gid):
        log.warning("trial confirmation refused", uid=caller.uid, gid=caller.gid,
                    pid=caller.pid, reason=ReasonCode.NO_AUTHORITY, detail=f"not in group {group}")
        return {"ok": False, "error": f"uid {caller.uid} is not in group {group}"}
    if request.command is OperatorCommand.STATUS:
        return {"ok": True, "run": run, "mode": "awaiting confirmation"}
    if request.command is not OperatorCommand.CONFIRM:
        return {"ok": False, "error": f"the trial {run} has not started: confirm it first"}
    log.info("trial confirmed", run=run, uid=caller.uid, gid=caller.gid, pid=caller.pid)
    if not confirmed.done():
        confirmed.set_result(caller)
    return {"ok": True, "confirmed": run, "uid": caller.uid}


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
