"""The safety monitor and warden as real processes, and the manifests they share.

Every manifest here is a shipped one with a test's changes written into its text: the UR cell
pointed at an emulator the test started itself (``[emulator] launch = false``, so warden drives
it as a real controller and the monitor knows its address), and a ``[safety]`` table whose
sockets live in the test's directory.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from kernel.safety.status import ask

ROOT = Path(__file__).resolve().parents[2]
MANIFESTS = ROOT / "manifests"
START_TIMEOUT_S = 60.0
FORCE_LIMIT_N = 150.0
"""Above the MuJoCo cell's insertion forces (its contact law keeps them near 25 N)."""


def safety_table(tmp: Path, **keys: Any) -> str:
    table = {"heartbeat_socket": str(tmp / "hb.sock"), "status_socket": str(tmp / "status.sock"),
             "max_wrist_force_n": FORCE_LIMIT_N, **keys}
    return "\n[safety]\n" + "".join(f"{key} = {json.dumps(value)}\n"
                                    for key, value in table.items() if value is not None)


def ur_manifest(tmp: Path, host: str, name: str = "cell.toml", **safety: Any) -> Path:
    """The UR cell on an emulator the test runs, as warden would drive a real controller: no
    device-side watchdog (``watchdog_periods = 0``), so the monitor is the only stop path when
    warden hangs."""
    text = (MANIFESTS / "sim-ur5e-rtde.toml").read_text()
    text = text.replace('name = "ur_rtde"', f'name = "ur_rtde"\nhost = "{host}"')
    text = text.replace("watchdog_periods = 25", "watchdog_periods = 0")
    text = text.replace('[emulator]\nplant = "mujoco"', "[emulator]\nlaunch = false")
    text = text.replace("cycles = 3", "cycles = 1\nsimulated_operator = false")
    text += f'\n[operator]\nsocket = "{tmp / "operator.sock"}"\n'
    path = tmp / name
    path.write_text(text + safety_table(tmp, **safety))
    return path


def canopen_manifest(tmp: Path, bus: dict[str, Any], name: str = "cell.toml",
                     driver: dict[str, Any] | None = None, **safety: Any) -> Path:
    """The CiA 402 cell on drives the test emulates itself (``bus``: the driver settings their
    emulator's READY line gives, interface, channel and udp_port), as on a robot PC; ``driver``
    replaces more ``[driver]`` keys of the shipped manifest."""
    text = (MANIFESTS / "sim-canopen.toml").read_text()
    for key, value in (driver or {}).items():
        old = next(line for line in text.splitlines() if line.startswith(f"{key} = "))
        text = text.replace(old, f"{key} = {json.dumps(value)}")
    keys = "".join(f"{key} = {json.dumps(value)}\n" for key, value in bus.items())
    text = text.replace('name = "canopen402"', f'name = "canopen402"\n{keys}', 1)
    text = text.replace('[emulator]\nplant = "mujoco"', "[emulator]\nlaunch = false")
    text = text.replace("cycles = 3", "cycles = 1\nsimulated_operator = false")
    text += f'\n[operator]\nsocket = "{tmp / "operator.sock"}"\n'
    path = tmp / name
    path.write_text(text + safety_table(tmp, **safety))
    return path


def sim_manifest(tmp: Path, port: int, name: str = "cell.toml", **safety: Any) -> Path:
    text = (MANIFESTS / "sim-ur5e.toml").read_text().replace("cycles = 3", "cycles = 1")
    path = tmp / name
    path.write_text(text + safety_table(tmp, sim_port=port, **safety))
    return path


def with_shoulder_limit(manifest: Path, upper: float, name: str) -> Path:
    """A copy whose joint 1 (shoulder lift) may not rise above ``upper``: a limit inside the
    cell's transport move (joint 1 starts at -1.571, dips to -1.75 at the part, then rises
    through -1.5 toward -1.37 on the way to the hole, about 2.8 s into the cycle)."""
    old = "position_limits = [[-6.2832, 6.2832], [-6.2832, 6.2832],"
    text = manifest.read_text()
    if text.count(old) != 1:
        raise AssertionError("the manifest's position limits are not the shipped ones")
    path = manifest.with_name(name)
    path.write_text(text.replace(old, f"position_limits = [[-6.2832, 6.2832], [-6.2832, {upper}],"))
    return path


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class Monitor:
    """``warden safety MANIFEST`` as a child process, logging JSON lines to a file."""

    def __init__(self, manifest: Path, tmp: Path) -> None:
        self.status_path = tmp / "status.sock"
        self.log_path = tmp / "monitor.log"
        self.process = subprocess.Popen(
            [sys.executable, "-m", "kernel.cli", "safety", str(manifest), "--log-format",
             "json"], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=self.log_path.open("w"))

    def wait_watching(self) -> dict[str, Any]:
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise AssertionError(f"the monitor exited {self.process.returncode}: "
                                     f"{self.log_path.read_text()}")
            try:
                return self.status()
            except (OSError, ValueError):
                time.sleep(0.05)
        raise AssertionError(f"the monitor never answered: {self.log_path.read_text()}")

    def wait_connected(self) -> dict[str, Any]:
        """The first status in which the monitor is watching the device (checking on time, its
        connection up); whether the arm is inside its limits is not asked: the first answer
        may already list a breach the test itself provokes (issue 15, item 14: taking the first
        answer's ``ok`` failed 5 of 15 isolated runs). Fails with the last answer at the
        deadline."""
        deadline = time.monotonic() + START_TIMEOUT_S
        status = self.wait_watching()
        while not (status["watching"] and status["connected"]):
            if time.monotonic() > deadline:
                raise AssertionError(f"the monitor never watched the device: {status}")
            time.sleep(0.01)
            status = self.status()
        return status

    def status(self) -> dict[str, Any]:
        return ask(self.status_path, 2.0)

    def events(self, name: str) -> list[dict[str, Any]]:
        lines = [json.loads(line) for line in self.log_path.read_text().splitlines()
                 if line.startswith("{")]
        return [line for line in lines if line.get("event") == name]

    def first_stop(self) -> dict[str, Any]:
        """The first confirmed ``safety stop`` line; failing, the log's end says what happened
        instead (a ``safety stop failed``, another breach, nothing)."""
        stops = self.events("safety stop")
        if not stops:
            raise AssertionError(f"no confirmed safety stop; the monitor's log ends "
                                 f"{self.log_path.read_text()[-3000:]}")
        return stops[0]

    def stop(self) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        return self.process.wait(timeout=30)


class Warden:
    """``warden run MANIFEST`` as a child process (``python -m kernel.cli run``)."""

    def __init__(self, manifest: Path, tmp: Path) -> None:
        self.log_path = tmp / "warden.log"
        self.process = subprocess.Popen(
            [sys.executable, "-m", "kernel.cli", "run", str(manifest), "--journal-dir",
             str(tmp / "runs"), "--log-format", "json"], cwd=ROOT,
            stdout=subprocess.DEVNULL, stderr=self.log_path.open("w"))

    @property
    def pid(self) -> int:
        return self.process.pid

    def alive(self) -> bool:
        return self.process.poll() is None

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGCONT)
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


def wait_for(condition, what: str, timeout_s: float = START_TIMEOUT_S,  # type: ignore
             poll_s: float = 0.01):
    """Poll ``condition()`` until it returns something true; that value."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(poll_s)
    raise AssertionError(f"timed out waiting for {what}")
