"""The RTDE server of the emulated controller (port 30004), protocol version 2.

Every message is ``uint16 size, uint8 type, payload`` (big-endian, size includes the header).
A session negotiates the protocol, asks the controller version, sets up one output recipe (a
frequency and variable names; we answer the UR types, ``NOT_FOUND`` for unknown names) and any
number of input recipes (ids 1..N in setup order; ``IN_USE`` when another session already writes
one of the variables), then starts. From then on the controller sends one data package per
output period and applies every data package the client sends to the registers.

Sessions are independent, as on the controller: any number of clients read at once (warden's
driver, and the safety monitor's own receive session), and one that stops reading (a stopped
process) never holds back the controller's cycle or another client. The cycle sends each
session's data package without waiting: what the client's socket cannot take yet waits in that
session's own buffer, and while that holds more than :data:`BACKLOG_PACKAGES` packages, new
ones are dropped for that session alone.
"""

from __future__ import annotations

import contextlib
import itertools
import select
import socket
import struct
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum

from stubs.ur_controller.frame import Frame, Provider, provider_for
from stubs.ur_controller.io_board import IOBoard
from stubs.ur_controller.status import RegisterBank
from stubs.ur_controller.ur_types import (
    IN_USE,
    NOT_FOUND,
    URType,
    Version,
    flatten,
    input_type,
    output_type,
    recipe_struct,
    unflatten,
)
from stubs.ur_controller.watchdog import RTDEWatchdogs

HEADER = struct.Struct(">HB")
PROTOCOL_VERSION = 2
SEND_TIMEOUT_S = 1.0
BACKLOG_PACKAGES = 64
"""Data packages a session may have waiting for its client (128 ms at 500 Hz)."""


class Message(IntEnum):
    REQUEST_PROTOCOL_VERSION = ord("V")
    GET_URCONTROL_VERSION = ord("v")
    TEXT_MESSAGE = ord("M")
    DATA_PACKAGE = ord("U")
    SETUP_OUTPUTS = ord("O")
    SETUP_INPUTS = ord("I")
    START = ord("S")
    PAUSE = ord("P")


@dataclass(frozen=True, slots=True)
class OutputRecipe:
    recipe_id: int
    providers: list[Provider]
    types: list[URType]
    packer: struct.Struct
    every_n_cycles: int

    def pack(self, frame: Frame) -> bytes:
        values = flatten(self.types, [provide(frame) for provide in self.providers])
        return bytes([self.recipe_id]) + self.packer.pack(*values)


@dataclass(frozen=True, slots=True)
class InputRecipe:
    names: list[str]
    types: list[URType]
    unpacker: struct.Struct


@dataclass(frozen=True, slots=True)
class ServerContext:
    """What a session needs from the controller."""

    version: tuple[int, int, int, int]
    cycle_hz: float
    registers: RegisterBank
    lock: threading.Lock
    io: IOBoard
    watchdogs: RTDEWatchdogs

    @property
    def short_version(self) -> Version:
        return self.version[:3]


class RTDESession:
    """One client connection; its reader thread answers requests and applies inputs."""

    _ids = itertools.count(1)

    def __init__(self, sock: socket.socket, context: ServerContext,
                 on_close: Callable[[RTDESession], None]) -> None:
        self.session_id = next(self._ids)
        self.sock = sock
        self.context = context
        self.started = False
        self.outputs: OutputRecipe | None = None
        self.inputs: dict[int, InputRecipe] = {}
        self._on_close = on_close
        self._send_lock = threading.Lock()
        self._closed = False
        self._backlog = b""
        """Bytes the client's socket has not taken yet, whole messages only at its end."""
        self.dropped = 0
        """Data packages dropped because this client did not read them in time."""
        self._writable = select.poll()
        self._writable.register(sock, select.POLLOUT)
        self._handlers: dict[int, Callable[[bytes], None]] = {
            Message.REQUEST_PROTOCOL_VERSION: self._negotiate,
            Message.GET_URCONTROL_VERSION: self._send_version,
            Message.SETUP_OUTPUTS: self._setup_outputs,
            Message.SETUP_INPUTS: self._setup_inputs,
            Message.START: self._start,
            Message.PAUSE: self._pause,
            Message.DATA_PACKAGE: self._apply_inputs,
            Message.TEXT_MESSAGE: lambda _: None,
        }
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(SEND_TIMEOUT_S)

    def serve(self) -> None:
        try:
            while True:
                kind, payload = self._read_message()
                self._dispatch(kind, payload)
        except (OSError, ConnectionError, EOFError):
            pass  # the client left, or a fault closed the socket
        finally:
            self.close()

    def send_data(self, frame: Frame, cycle: int) -> None:
        """This cycle's package, sent without waiting for a client that does not read."""
        recipe = self.outputs
        if recipe is None or cycle % recipe.every_n_cycles:
            return
        package = recipe.pack(frame)
        message = HEADER.pack(HEADER.size + len(package), Message.DATA_PACKAGE) + package
        with self._send_lock:
            if self._closed:
                return
            if len(self._backlog) > BACKLOG_PACKAGES * len(message):
                self.dropped += 1
                return
            self._backlog += message
            if self._writable.poll(0):  # send what fits now; the rest waits for next cycle
                self._backlog = self._backlog[self.sock.send(self._backlog):]

    def close(self) -> None:
        with self._send_lock:
            if self._closed:
                return
            self._closed = True
        self.started = False
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()
        with self.context.lock:
            self.context.registers.release(self.session_id)
        self._on_close(self)

    def _read_message(self) -> tuple[int, bytes]:
        size, kind = HEADER.unpack(self._read_exactly(HEADER.size))
        return kind, self._read_exactly(size - HEADER.size)

    def _read_exactly(self, count: int) -> bytes:
        chunks, remaining = [], count
        while remaining > 0:
            try:
                chunk = self.sock.recv(remaining)
            except TimeoutError:
                continue  # idle clients are fine; the timeout only bounds our sends
            if not chunk:
                raise EOFError
            chunks.append(chunk)
            remaining -= len(chunk)
        return b"".join(chunks)

    def _dispatch(self, kind: int, payload: bytes) -> None:
        handler = self._handlers.get(kind)
        if handler is None:
            print(f"ur_controller: RTDE message type {kind} ignored", file=sys.stderr)
            return
        handler(payload)

    def _negotiate(self, payload: bytes) -> None:
        (requested,) = struct.unpack(">H", payload[:2])
        self._send(Message.REQUEST_PROTOCOL_VERSION, bytes([requested == PROTOCOL_VERSION]))

    def _send_version(self, _: bytes) -> None:
        self._send(Message.GET_URCONTROL_VERSION, struct.pack(">4I", *self.context.version))

    def _setup_outputs(self, payload: bytes) -> None:
        (frequency,) = struct.unpack(">d", payload[:8])
        names = _names(payload[8:])
        found = [output_type(name, self.context.short_version) for name in names]
        answer = [t.value if t is not None else NOT_FOUND for t in found]
        valid = bool(names) and None not in found and 0 < frequency <= self.context.cycle_hz
        recipe_id = 1 if valid else 0
        if valid:
            types = [t for t in found if t is not None]
            self.outputs = OutputRecipe(
                recipe_id, [provider_for(n, t) for n, t in zip(names, types, strict=True)],
                types, recipe_struct(types), max(1, round(self.context.cycle_hz / frequency)),
            )
        self._send(Message.SETUP_OUTPUTS, bytes([recipe_id]) + ",".join(answer).encode())

    def _setup_inputs(self, payload: bytes) -> None:
        names = _names(payload)
        with self.context.lock:
            answer = [self._input_answer(name) for name in names]
            valid = bool(names) and not {IN_USE, NOT_FOUND} & set(answer)
            if valid:
                self.context.registers.claim(names, self.session_id)
        recipe_id = 0
        if valid:
            recipe_id = len(self.inputs) + 1
            types = [URType(t) for t in answer]
            self.inputs[recipe_id] = InputRecipe(names, types, recipe_struct(types))
        self._send(Message.SETUP_INPUTS, bytes([recipe_id]) + ",".join(answer).encode())

    def _input_answer(self, name: str) -> str:
        kind = input_type(name, self.context.short_version)
        if kind is None:
            return NOT_FOUND
        if self.context.registers.taken_by_other(name, self.session_id):
            return IN_USE
        return kind.value

    def _start(self, _: bytes) -> None:
        started = self.outputs is not None or bool(self.inputs)
        self._send(Message.START, bytes([started]))
        self.started = started  # after the answer: no data package may overtake it

    def _pause(self, _: bytes) -> None:
        self.started = False
        self._send(Message.PAUSE, bytes([1]))

    def _apply_inputs(self, payload: bytes) -> None:
        recipe = self.inputs.get(payload[0]) if payload else None
        if recipe is None or len(payload) - 1 != recipe.unpacker.size:
            print(f"ur_controller: bad input package (recipe {payload[:1]!r})", file=sys.stderr)
            return
        values = unflatten(recipe.types, recipe.unpacker.unpack(payload[1:]))
        with self.context.lock:
            self.context.registers.write(recipe.names, values)
            self.context.watchdogs.saw(recipe.names)
            self.context.io.apply(recipe.names, values)

    def _send(self, kind: int, payload: bytes) -> None:
        """An answer: it must arrive (after any data still waiting), within the send timeout."""
        message = HEADER.pack(HEADER.size + len(payload), kind) + payload
        with self._send_lock:
            if not self._closed:
                backlog, self._backlog = self._backlog + message, b""
                self.sock.sendall(backlog)


def _names(payload: bytes) -> list[str]:
    return [name for name in payload.decode(errors="replace").split(",") if name]
