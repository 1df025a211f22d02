"""The simulated cell on the wall clock, with the policy server as a process and a real
websocket between them: the live decisions are exactly what the journal replays, and the
service manager hears READY and watchdog pings while the loop runs."""

from __future__ import annotations

import json
import os
import socket
import threading
from pathlib import Path

import pytest

from kernel.app.live import run_live
from kernel.shell.loop import run
from tests.cell.harness import manifest, replays_identically, run_dir

pytestmark = pytest.mark.slow


class _ServiceManager:
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


def test_live_cycle_over_the_websocket_replays_exactly(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    address = str(tmp_path / "notify.sock")
    systemd = _ServiceManager(address)
    monkeypatch.setenv("NOTIFY_SOCKET", address)
    monkeypatch.setenv("WATCHDOG_USEC", "2000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    try:
        summary = run(run_live(manifest("sim-ur5e.toml", cycles=1), tmp_path / "runs"))
    finally:
        messages = systemd.close()
    assert summary["cycles"]["attempted"] == 1
    link = summary["link"]
    assert link["handshakes_accepted"] >= 1
    assert link["chunks_admitted"] > 5
    assert summary["loop"]["ticks"] > 1000
    directory = run_dir(tmp_path / "runs")
    assert replays_identically(directory)
    assert json.loads((directory / "summary.json").read_text())["cycles"]["attempted"] == 1
    assert any("READY=1" in m for m in messages)
    assert sum("WATCHDOG=1" in m for m in messages) >= 2
    assert "STOPPING=1" in messages[-1], messages[-3:]
