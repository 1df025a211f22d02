"""The operator socket's connections, each bounded: one request line in, one answer line out.

Whoever may connect to the socket (the operator group, or anyone if its permissions were
loosened by mistake) must not be able to keep the operators out of it, nor to break the run
that serves it. So every connection is bounded (:class:`SocketLimits`): a request line longer
than ``max_line`` is answered with an error; a connection that has not sent its line within
``idle_timeout_s`` is answered with an error and closed; one uid holds at most ``per_uid``
connections at once (one more is answered with an error and closed at once, without being read);
and the kernel queues up to ``backlog`` connections that are not accepted yet, so a burst of
connects does not turn the next operator's connect away (``EAGAIN``) before warden has
accepted and answered them.

The connections are tasks of the server's own TaskGroup: when the server stops, they stop with
it, and nothing outlives the run.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import json
import os
import socket
import struct
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import structlog

log = structlog.get_logger("warden.operator")
_CREDENTIALS = struct.Struct("3i")  # struct ucred: pid, uid, gid
_OUT_OF_RESOURCES = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
_ACCEPT_BACKOFF_S = 0.1

Answer = dict[str, Any]


@dataclass(frozen=True, slots=True)
class SocketLimits:
    max_line: int = 4096
    """Bytes of one request line (a request is a few dozen)."""
    idle_timeout_s: float = 2.0
    """How long a connection may take to send its line (a client sends it as it connects)."""
    per_uid: int = 16
    """Connections one uid may hold open at once."""
    backlog: int = 1024
    """Connections the kernel queues before warden accepts them (capped by somaxconn)."""


DEFAULT_LIMITS = SocketLimits()


@dataclass(frozen=True, slots=True)
class Caller:
    pid: int
    uid: int
    gid: int


Handler = Callable[[Caller, bytes, int], Awaitable[Answer]]
"""Answers one request line from ``caller``, received at the monotonic instant given in ns."""


class LineServer:
    """Serves one Unix socket, ``0660`` and owned by group ``gid``, with :class:`SocketLimits`."""

    def __init__(self, path: Path, gid: int, handle: Handler,
                 limits: SocketLimits = DEFAULT_LIMITS) -> None:
        self.path, self.gid, self.handle, self.limits = path, gid, handle, limits
        self._open: dict[int, int] = {}  # uid -> connections open
        self._at_limit: set[int] = set()  # uids whose turning away has been logged
        self._listener: socket.socket | None = None

    def open(self) -> None:
        """Bind and listen (the socket file appears, ``0660``, group ``gid``).

        Raises:
            OSError: the path cannot be bound (exists, no such directory, not allowed).
        """
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            listener.bind(str(self.path))
            listener.listen(self.limits.backlog)  # at once: a client that sees the file connects
            listener.setblocking(False)
            os.chown(self.path, 0 if os.geteuid() == 0 else -1, self.gid)
            os.chmod(self.path, 0o660)
        except BaseException:
            listener.close()
            raise
        self._listener = listener

    async def serve(self, started: Callable[[], None] | None = None) -> None:
        """Serve the opened socket until cancelled; then close it (its file removed)."""
        listener = self._listener
        if listener is None:
            raise RuntimeError("LineServer.serve before open")
        try:
            if started is not None:
                started()
            async with asyncio.TaskGroup() as connections:
                while True:
                    connection = await self._accept(listener)
                    if connection is not None:
                        self._admit(connections, connection)
        finally:
            self.close()

    async def _accept(self, listener: socket.socket) -> socket.socket | None:
        """The next connection, or None: it went away before it was accepted, or the process
        is out of descriptors or memory for now (the server waits a moment, as asyncio's own
        server does, instead of failing the run)."""
        try:
            connection, _ = await asyncio.get_running_loop().sock_accept(listener)
        except ConnectionAbortedError:
            return None
        except OSError as error:
            if error.errno not in _OUT_OF_RESOURCES:
                raise
            log.warning("operator socket cannot accept", error=errno.errorcode[error.errno])
            await asyncio.sleep(_ACCEPT_BACKOFF_S)
            return None
        connection.setblocking(False)
        return connection

    def close(self) -> None:
        """Stop listening and remove the socket file; idempotent."""
        if self._listener is None:
            return
        self._listener.close()
        self._listener = None
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

    def open_connections(self, uid: int) -> int:
        return self._open.get(uid, 0)

    def _admit(self, connections: asyncio.TaskGroup, connection: socket.socket) -> None:
        caller = _credentials(connection)
        count = self._open.get(caller.uid, 0)
        if count >= self.limits.per_uid:
            self._turn_away(connection, caller)
            return
        self._open[caller.uid] = count + 1
        connections.create_task(self._connection(connection, caller))

    def _turn_away(self, connection: socket.socket, caller: Caller) -> None:
        """Past the uid's bound: one answer, written at once (it fits in an empty socket
        buffer), and the connection closed unread; logged once per stretch at the bound."""
        if caller.uid not in self._at_limit:
            self._at_limit.add(caller.uid)
            log.warning("operator connections at the limit", uid=caller.uid, pid=caller.pid,
                        limit=self.limits.per_uid)
        error = (f"uid {caller.uid} has {self.limits.per_uid} connections open to this socket "
                 "(the limit): close one and retry")
        with contextlib.suppress(OSError), connection:
            connection.send(_line({"ok": False, "error": error}))

    async def _connection(self, connection: socket.socket, caller: Caller) -> None:
        received_ns = time.monotonic_ns()
        try:
            reader, writer = await asyncio.open_unix_connection(sock=connection,
                                                                limit=self.limits.max_line)
        except OSError:
            connection.close()
            self._closed(caller)
            return
        try:
            line = await self._read_line(reader)
            answer = line  # an error answer, or None
            if isinstance(line, bytes):
                answer = await self.handle(caller, line, received_ns)
            if answer is not None:
                writer.write(_line(answer))
                async with asyncio.timeout(self.limits.idle_timeout_s):
                    await writer.drain()
        except (TimeoutError, ConnectionError, OSError):
            pass  # a client that went away, or does not read its answer, gets nothing more
        finally:
            writer.close()
            self._closed(caller)

    async def _read_line(self, reader: asyncio.StreamReader) -> bytes | Answer | None:
        """The request line, an error answer instead of it, or None: the client left silently."""
        limits = self.limits
        try:
            async with asyncio.timeout(limits.idle_timeout_s):
                return await reader.readuntil(b"\n")
        except asyncio.LimitOverrunError:
            return {"ok": False, "error": f"request longer than {limits.max_line} bytes: "
                                          "one JSON object on one line expected"}
        except asyncio.IncompleteReadError as ended:  # the client closed without a newline
            return ended.partial or None
        except TimeoutError:
            return {"ok": False, "error": f"no request line within {limits.idle_timeout_s:g} s"}

    def _closed(self, caller: Caller) -> None:
        left = self._open[caller.uid] - 1
        if left:
            self._open[caller.uid] = left
        else:
            del self._open[caller.uid]
        if left < self.limits.per_uid:
            self._at_limit.discard(caller.uid)


class DuplicateKey(ValueError):
    pass


def reject_duplicate_keys(line: bytes) -> None:
    """JSON decoders keep the last of two equal keys (``{"command": "status", "command":
    "stop"}`` is a stop); a request says each thing once.

    Raises:
        DuplicateKey: a key appears twice in one object.
        ValueError: not JSON at all.
    """
    json.loads(line, object_pairs_hook=_unique)


def _unique(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    seen: dict[str, Any] = {}
    for key, value in pairs:
        if key in seen:
            raise DuplicateKey(f"duplicate key {key!r}")
        seen[key] = value
    return seen


def _credentials(connection: socket.socket) -> Caller:
    raw = connection.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _CREDENTIALS.size)
    pid, uid, gid = _CREDENTIALS.unpack(raw)
    return Caller(pid, uid, gid)


def _line(answer: Answer) -> bytes:
    return json.dumps(answer).encode() + b"\n"
