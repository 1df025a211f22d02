"""One warden per device: a second `warden run` or `warden check` on a device a running warden
drives exits 2 naming the holder, before it touches the device, and the first run is unaffected.

The cell test runs real processes (`python -m kernel.cli`) against an emulator the test started
itself, as an integrator's second terminal would on a robot PC; the lock directory is the test's
own (``WARDEN_LOCK_DIR``). The identities of all three vendor drivers, and a lock whose holder
was killed, are tested without a cell.
"""

from __future__ import annotations

import json
import os
import pty
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from drivers import registry
from kernel.manifest import load_manifest
from kernel.shell.device_lock import LOCK_DIR_ENV, DeviceBusy, Holder, acquire
from kernel.signing import generate_keypair, sign
from stubs.cell.emulated import LAUNCHERS
from stubs.process import EmulatorProcess
from tests.cell.harness import MANIFESTS

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = {"ur_rtde": "sim-ur5e-rtde.toml", "dynamixel": "sim-dynamixel.toml",
           "canopen402": "sim-canopen.toml"}
START_TIMEOUT_S = 60.0
RUN_TIMEOUT_S = 240.0


def _cycle_under_way(log: Path) -> bool:
    """The run's JSON progress lines (its stderr is a file: JSON logs) show cycle 1 begun."""
    for line in log.read_bytes().splitlines():
        try:
            entry = json.loads(line)
        except ValueError:
            continue
        if isinstance(entry, dict) and entry.get("event") == "progress" and (
                entry.get("cycle") == 1):
            return True
    return False


JOINTS: dict[str, dict[str, Any]] = {
    "canopen402": {"node_ids": [1, 2], "counts_per_rev": [4096, 4096]}}
"""What a table needs besides its address to be settings at all."""


def _identity(driver: str, table: dict[str, Any]) -> str | None:
    settings = registry.settings_for(driver, {**JOINTS.get(driver, {}), **table}, "driver")
    return registry.load(driver).device_identity(settings)


# -- identities: one string per device, whatever the manifest calls it ----------------------------

def test_ur_identity_is_the_controllers_address() -> None:
    assert _identity("ur_rtde", {"host": "::1"}) == _identity("ur_rtde",
                                                              {"host": "0:0:0:0:0:0:0:1"})
    assert _identity("ur_rtde", {"host": "Robot.Local."}) == _identity("ur_rtde",
                                                                       {"host": "robot.local"})
    assert _identity("ur_rtde", {"host": "127.0.0.2"}) != _identity("ur_rtde",
                                                                    {"host": "127.0.0.3"})


def test_dynamixel_identity_is_the_serial_port_behind_its_links(tmp_path: Path) -> None:
    parent, child = pty.openpty()
    try:
        port = os.ttyname(child)
        link = tmp_path / "by-id-usb-adapter"
        link.symlink_to(port)
        assert _identity("dynamixel", {"port": str(link)}) == _identity("dynamixel",
                                                                        {"port": port})
        assert port in str(_identity("dynamixel", {"port": str(link)}))
    finally:
        os.close(parent)
        os.close(child)


def test_canopen_identity_is_the_interface_and_channel() -> None:
    can0 = _identity("canopen402", {"interface": "socketcan", "channel": "can0"})
    assert can0 != _identity("canopen402", {"interface": "socketcan", "channel": "can1"})
    udp = {"interface": "udp_multicast", "channel": "239.0.0.1"}
    assert _identity("canopen402", udp) != _identity("canopen402", {**udp, "udp_port": 43114})
    assert _identity("canopen402", {"interface": "virtual", "channel": "x"}) is None


# -- the lock itself -----------------------------------------------------------------------------

HOLD = """
import os, sys, time
from kernel.shell.device_lock import Holder, acquire
acquire(sys.argv[1], Holder(sys.argv[2]), {"command": "holder", "run": "held"})
print("held", flush=True)
time.sleep(600)
"""


def _holder(device: str, holder: Holder, env: dict[str, str]) -> subprocess.Popen[str]:
    process = subprocess.Popen([sys.executable, "-c", HOLD, device, holder], cwd=ROOT, env=env,
                               stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None and process.stdout.readline() == "held\n"
    return process


def test_a_lock_held_by_a_killed_process_is_free_again(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(LOCK_DIR_ENV, str(tmp_path))
    device = "CAN bus socketcan can7"
    process = _holder(device, Holder.WARDEN, {**os.environ})
    try:
        with pytest.raises(DeviceBusy, match=f"pid {process.pid}, `holder`, run held"):
            acquire(device, Holder.WARDEN, {})
        # The monitor's lock is another: warden's never blocks the safety monitor.
        acquire(device, Holder.MONITOR, {}).release()
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait()
    acquire(device, Holder.WARDEN, {}).release()  # the kernel released the dead one's flock


def test_two_monitors_on_one_device_are_refused(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(LOCK_DIR_ENV, str(tmp_path))
    process = _holder("UR controller 127.0.0.9", Holder.MONITOR, {**os.environ})
    try:
        with pytest.raises(DeviceBusy, match="another safety monitor"):
            acquire("UR controller 127.0.0.9", Holder.MONITOR, {})
    finally:
        process.kill()
        process.wait()


# -- a second warden against a running cell ------------------------------------------------------

def _manifest(tmp_path: Path, driver: str, settings: dict[str, Any], key: Path) -> Path:
    """The shipped manifest as a real device's: the emulator's address, nothing launched, no
    simulated operator, one cycle, an operator socket of the test's own; signed."""
    text = (MANIFESTS / SHIPPED[driver]).read_text()
    lines = "".join(f"{name} = {json.dumps(value)}\n" for name, value in settings.items())
    text = text.replace("[driver]\n", f"[driver]\n{lines}", 1)
    text = text.replace("[emulator]\n", "[emulator]\nlaunch = false\n", 1)
    text = text.replace("[cell]\n", "[cell]\nsimulated_operator = false\n", 1)
    text = text.replace("cycles = 3", "cycles = 1", 1)
    text += f'\n[operator]\nsocket = "{tmp_path / "operator.sock"}"\n'
    path = tmp_path / "cell.toml"
    path.write_text(text)
    sign(path, key)
    return path


def _warden(*args: str, env: dict[str, str], log: Path) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-m", "kernel.cli", *args], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=log.open("w"))


PRIMED = """
import os, sys
import kernel.app.check, kernel.app.live, kernel.cli, pinocchio  # the imports of a start-up
os.nice(10)
print("primed", flush=True)
sys.stdin.readline()
sys.exit(kernel.cli.main(sys.argv[1:]))
"""


class Second:
    """A `warden` command started ahead with its imports done, run on :meth:`go`, niced: on the
    2-core test machine a whole Python start-up takes seconds, long enough for the first run to
    end, and one competing for CPU starved the first one's policy server (chunks late,
    UNDERRUN) or its CANopen bring-up (an SDO reply later than 0.3 s). What the lock keeps from
    the first run is the device, not CPU time."""

    def __init__(self, *args: str, env: dict[str, str], log: Path) -> None:
        self.log = log
        self.process = subprocess.Popen(
            [sys.executable, "-c", PRIMED, *args], cwd=ROOT, env=env, stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=log.open("w"), text=True)
        assert self.process.stdout is not None
        assert self.process.stdout.readline() == "primed\n", log.read_text()

    def go(self) -> tuple[int, str]:
        assert self.process.stdin is not None
        self.process.stdin.write("go\n")
        self.process.stdin.close()
        code = self.process.wait(timeout=START_TIMEOUT_S)
        return code, self.log.read_text()

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()


def _holding(locks: Path, pid: int) -> dict[str, Any] | None:
    """The lock record of ``pid`` once its run directory is in it."""
    for path in locks.glob("warden-*.lock"):
        text = path.read_text()
        record = json.loads(text) if text else {}
        if record.get("pid") == str(pid) and "directory" in record:
            return record
    return None


@pytest.mark.slow
@pytest.mark.parametrize("driver", ["ur_rtde"])
def test_a_second_warden_on_a_running_cell_exits_2_and_the_first_cycle_verifies(
        tmp_path: Path, driver: str) -> None:
    """On the UR cell only: the lock is taken by the same code for every driver
    (kernel/shell/device_lock.py, from the driver's ``device_identity``), and each driver's
    identity is pinned without a cell by the identity tests above (a CANopen cell here cost a
    whole emulated cycle more in `make test`)."""
    trusted = tmp_path / "trusted"
    trusted.mkdir()
    generate_keypair(tmp_path / "signer.key", trusted / "signer.pub")
    launch = LAUNCHERS[driver](load_manifest(MANIFESTS / SHIPPED[driver]), "mujoco")
    emulator = EmulatorProcess(launch.module, *launch.args).start()
    env = {**os.environ, LOCK_DIR_ENV: str(tmp_path / "locks")}
    first: subprocess.Popen[bytes] | None = None
    seconds: list[Second] = []
    try:
        path = _manifest(tmp_path, driver, launch.settings(emulator.info),
                         tmp_path / "signer.key")
        seconds = [Second("run", str(path), "--journal-dir", str(tmp_path / "runs"), env=env,
                          log=tmp_path / "second-run.log"),
                   Second("check", str(path), "--keys", str(trusted), "--seconds", "1",
                          env=env, log=tmp_path / "second-check.log")]
        first = _warden("run", str(path), "--journal-dir", str(tmp_path / "runs"), "--json",
                        str(tmp_path / "first.json"), env=env, log=tmp_path / "first.log")
        deadline = time.monotonic() + START_TIMEOUT_S
        record = None
        while record is None and first.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
            record = _holding(tmp_path / "locks", first.pid)
        assert record is not None, (tmp_path / "first.log").read_text()
        # The second commands start once the first is up and moving (its bring-up, SDO
        # timeouts and all, is behind it): the lock refuses them before they touch anything.
        while not _cycle_under_way(tmp_path / "first.log") and first.poll() is None:
            time.sleep(0.05)
        assert first.poll() is None, "the first run ended on its own before any second one " \
            f"started: {(tmp_path / 'first.log').read_text()}"
        for second in seconds:
            code, err = second.go()
            assert code == 2, err
            assert f"pid {first.pid}" in err and f"run {record['run']}" in err, err
            assert record["directory"] in err and "Traceback" not in err, err
            assert first.poll() is None, "the first run ended before the second was refused"
        assert first.wait(timeout=RUN_TIMEOUT_S) == 0, (tmp_path / "first.log").read_text()
        cycles = json.loads((tmp_path / "first.json").read_text())["cycles"]
        assert cycles["verified"] == cycles["attempted"] == 1
        assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == [
            Path(record["directory"]).name]  # the second ones never made a run directory
    finally:
        for second in seconds:
            second.kill()
        if first is not None and first.poll() is None:
            first.kill()
            first.wait()
        emulator.stop()
