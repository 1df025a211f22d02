"""Manifests for cell tests: the shipped ones, with a test's overrides and a temp journal; what
the shared driver cycles (tests/cell/conftest.py) give their tests."""

from __future__ import annotations

import dataclasses
import os
import socket
import threading
from pathlib import Path
from typing import Any, NamedTuple

import msgspec

from kernel.app.session import RunContext
from kernel.core.lines import encode
from kernel.manifest import ClockKind, Manifest, load_manifest
from kernel.replay import Replay
from kernel.scenario.load import load_scenario
from tests.net import OpenSocket, inet_sockets, process_tree

MANIFESTS = Path(__file__).resolve().parents[2] / "manifests"


def manifest(name: str, cycles: int = 1, clock: ClockKind | None = None) -> Manifest:
    loaded = load_manifest(MANIFESTS / name)
    cell = msgspec.structs.replace(loaded.cell, cycles=cycles, clock=clock or loaded.cell.clock)
    return dataclasses.replace(loaded, cell=cell)


def run_dir(journal_root: Path) -> Path:
    (directory,) = [p for p in journal_root.iterdir() if p.is_dir()]
    return directory


def replays_identically(directory: Path) -> bool:
    """The journal of a run, replayed, gives the run's decision log byte for byte and every
    command the run wrote to its driver bit for bit."""
    replay = Replay(load_scenario(directory / "journal.jsonl"))
    replayed = b"".join(encode(line) + b"\n" for line in replay.lines())
    return (replayed == (directory / "decisions.jsonl").read_bytes()
            and replay.first_difference is None and replay.commands_checked > 0)


DRIVER_MANIFESTS = ["sim-ur5e-rtde.toml", "sim-dynamixel.toml", "sim-canopen.toml"]


class DriverCycle(NamedTuple):
    summary: dict[str, Any]
    directory: Path
    sockets: list[OpenSocket]
    """This process's and its children's sockets while the cycle ran (tests/net.py)."""


class SocketsWhileRunning:
    """A tick hook that never ends the run: after ``after_ticks`` ticks it lists the sockets of
    this process and its children, on a thread of its own (``ss`` takes milliseconds the
    control loop must not lose)."""

    def __init__(self, after_ticks: int) -> None:
        self.after_ticks = after_ticks
        self.ticks = 0
        self.found: list[OpenSocket] = []
        self._thread: threading.Thread | None = None

    def __call__(self, context: RunContext) -> bool:
        self.ticks += 1
        if self.ticks == self.after_ticks:
            self._thread = threading.Thread(target=self._list, daemon=True)
            self._thread.start()
        return False

    def _list(self) -> None:
        self.found = inet_sockets(process_tree(os.getpid()))

    def sockets(self) -> list[OpenSocket]:
        if self._thread is not None:
            self._thread.join(timeout=30)
        return self.found


class SimCycle(NamedTuple):
    summary: dict[str, Any]
    directory: Path
    sockets: list[OpenSocket]
    notified: list[str]
    """What the stand-in service manager heard (NOTIFY_SOCKET datagrams), in order."""


class ServiceManager:
    """Stands in for systemd's notify socket: drains datagrams while the run goes on (a unix
    datagram queue holds only ~10 messages)."""

    def __init__(self, path: str) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(path)
        self.sock.settimeout(0.1)
        self.messages: list[str] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._drain, daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        while not self._stop.is_set():
            try:
                self.messages.append(self.sock.recv(4096).decode())
            except TimeoutError:
                continue

    def close(self) -> list[str]:
        self._stop.set()
        self._thread.join()
        self.sock.close()
        return self.messages
