"""manifests/warden.service: the settings the runtime relies on, and systemd's own verdict."""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from kernel import cli_run, signing

ROOT = Path(__file__).resolve().parents[2]
UNIT = ROOT / "manifests" / "warden.service"
VENV_WARDEN = "/opt/warden/.venv/bin/warden"


def _settings() -> dict[str, list[str]]:
    """Every active ``Key=value`` of the unit (comments skipped), values in file order."""
    found: dict[str, list[str]] = {}
    for line in UNIT.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith(("#", ";", "[")):
            continue
        key, _, value = line.partition("=")
        found.setdefault(key, []).append(value)
    return found


def _one(key: str) -> str:
    values = _settings()[key]
    assert len(values) == 1, (key, values)
    return values[0]


def test_notify_and_watchdog() -> None:
    assert _one("Type") == "notify"
    assert _one("NotifyAccess") == "main"
    assert _one("WatchdogSec") == "2"
    assert _one("Restart") == "on-failure"
    assert int(_one("RestartSec")) >= 1
    assert int(_one("StartLimitBurst")) >= 1 and int(_one("StartLimitIntervalSec")) > 0
    assert set(_one("RestartPreventExitStatus").split()) == {"1", "2", "3"}


def test_realtime_is_permitted_without_root() -> None:
    assert set(_one("AmbientCapabilities").split()) == {"CAP_SYS_NICE", "CAP_IPC_LOCK"}
    assert set(_one("CapabilityBoundingSet").split()) == {"CAP_SYS_NICE", "CAP_IPC_LOCK"}
    assert _one("LimitMEMLOCK") == "infinity"
    assert int(_one("LimitRTPRIO")) >= 50  # kernel.shell.realtime asks for priority 50
    settings = _settings()
    assert _one("User") not in ("", "root")
    # Settings that would silently take real time or devices away.
    for forbidden in ("RestrictRealtime", "CPUSchedulingPolicy", "PrivateDevices",
                      "MemoryDenyWriteExecute", "DynamicUser"):
        assert forbidden not in settings, forbidden


def test_hardening_keeps_the_journal_writable() -> None:
    assert _one("ProtectSystem") == "strict"
    assert _one("NoNewPrivileges") == "yes"
    assert _one("PrivateTmp") == "yes"
    workdir = _one("WorkingDirectory")
    assert workdir in _one("ReadWritePaths").split()
    assert workdir == f"/var/lib/{_one('StateDirectory')}"


def test_commands_parse_with_the_warden_cli() -> None:
    parser = argparse.ArgumentParser(prog="warden")
    commands = parser.add_subparsers(dest="command", required=True)
    cli_run.add_commands(commands)
    signing.add_commands(commands)
    start = shlex.split(_one("ExecStart"))
    assert start[0] == VENV_WARDEN
    run = parser.parse_args(start[1:])
    assert run.command == "run" and run.manifest == "/etc/warden/cell.toml"
    assert run.keys == "/etc/warden/keys"  # verified in-process, on the bytes that run
    assert run.await_confirmation  # a held start: booting never moves the arm
    pre = shlex.split(_one("ExecStartPre"))
    check = parser.parse_args(pre[1:])
    assert check.handler is signing._verify_command
    assert check.manifest == run.manifest and check.keys == "/etc/warden/keys"


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
def test_systemd_analyze_verify(tmp_path: Path) -> None:
    # verify insists that ExecStart= exists; point it at this checkout's warden instead of the
    # /opt/warden convention, and change nothing else.
    warden = Path(sys.executable).with_name("warden")
    if not warden.exists():
        pytest.skip("the warden entry point is not installed in this venv")
    copy = tmp_path / "warden.service"
    copy.write_text(UNIT.read_text().replace(VENV_WARDEN, str(warden)))
    done = subprocess.run(["systemd-analyze", "verify", str(copy)], capture_output=True,
                          text=True, timeout=60, check=False)
    assert done.returncode == 0 and "warden.service" not in done.stderr, done.stderr


@pytest.mark.slow
def test_the_shipped_unit_cannot_move_the_arm_without_a_confirmation(tmp_path: Path) -> None:
    """The unit's own ExecStart (this checkout's warden, a signed copy of the emulated UR
    cell, the test keys), in the environment systemd gives it: ready and held, pinging the
    watchdog, no motion command reaching the controller and no run started until `warden
    operator confirm`; then the watchdog is lengthened for the bring-up, restored by the
    loop's READY, and the arm moves."""
    from kernel.cli_operator import send
    from kernel.signing import sign
    from stubs.fault_control import inject
    from stubs.ur_controller.launch import EmulatedController
    from tests.cell.test_trial import TEST_KEYS, TEST_SIGNER
    from tests.ops.test_sd_notify import Receiver
    from tests.safety.support import ur_manifest, wait_for

    warden = Path(sys.executable).with_name("warden")
    runtime = tmp_path / "run"
    runtime.mkdir()
    receiver = Receiver(str(tmp_path / "notify.sock"))
    with EmulatedController(plant="kinematic") as emulator:
        manifest = ur_manifest(tmp_path, emulator.host)
        text = manifest.read_text()
        manifest.write_text(text.replace(f'socket = "{tmp_path / "operator.sock"}"\n', ""))
        sign(manifest, TEST_SIGNER)
        command = _one("ExecStart").replace(VENV_WARDEN, str(warden)).replace(
            "/etc/warden/cell.toml", str(manifest)).replace("/etc/warden/keys", str(TEST_KEYS))
        env = {**os.environ, "NOTIFY_SOCKET": str(tmp_path / "notify.sock"),
               "WATCHDOG_USEC": "2000000", "RUNTIME_DIRECTORY": str(runtime)}
        env.pop("WATCHDOG_PID", None)
        motion = lambda: inject((emulator.host, int(emulator.info["control_port"])),  # noqa: E731
                                "motion")["motion_commands"]
        process = subprocess.Popen(shlex.split(command), cwd=tmp_path, env=env,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            first = _datagram(receiver, process)
            assert first.startswith(b"READY=1\nSTATUS=held: nothing moves until `warden "
                                    b"operator confirm"), first
            sock = runtime / "operator.sock"
            assert send(str(sock), "status", 5.0) == {
                "ok": True, "run": "sim-ur5e-rtde", "mode": "awaiting confirmation"}
            assert send(str(sock), "accept-recovery", 5.0)["ok"] is False  # only confirm
            pings = [_datagram(receiver, process) for _ in range(2)]
            assert pings == [b"WATCHDOG=1", b"WATCHDOG=1"], pings  # the hold is alive
            assert motion() == 0 and not list(tmp_path.glob("runs/*"))  # nothing started
            assert process.poll() is None
            assert send(str(sock), "confirm", 5.0)["ok"]
            seen = [_datagram(receiver, process)]
            assert seen[0] == b"WATCHDOG_USEC=90000000", seen  # the bring-up's bound
            while not seen[-1].startswith(b"READY=1"):
                seen.append(_datagram(receiver, process))
            assert seen[-1].endswith(b"\nWATCHDOG_USEC=2000000"), seen  # the loop: it is back
            wait_for(lambda: motion() > 0, "the first motion command", timeout_s=30)
        finally:
            process.terminate()
            _, err = process.communicate(timeout=60)
            receiver.sock.close()
    assert "Traceback" not in err, err[-3000:]


def _datagram(receiver: Any, process: subprocess.Popen[str], tries: int = 30) -> bytes:
    """The next notification (status lines skipped), while the process lives."""
    for _ in range(tries):
        try:
            data: bytes = receiver.recv()
        except TimeoutError:
            if process.poll() is not None:
                raise AssertionError(f"warden exited {process.returncode}") from None
            continue
        if not data.startswith(b"STATUS="):
            return data
    raise AssertionError("no notification")


def test_stopped_while_held_nothing_starts(tmp_path: Path) -> None:
    """`systemctl stop` (SIGTERM) while the unit holds: exit 143, said on stderr, no run
    directory; the device (an address nothing listens on) is never contacted."""
    from kernel.signing import sign
    from tests.cell.test_trial import TEST_KEYS, TEST_SIGNER
    from tests.ops.test_sd_notify import Receiver
    from tests.safety.support import ur_manifest

    runtime = tmp_path / "run"
    runtime.mkdir()
    receiver = Receiver(str(tmp_path / "notify.sock"))
    manifest = ur_manifest(tmp_path, "127.0.0.1")
    manifest.write_text(manifest.read_text().replace(
        f'socket = "{tmp_path / "operator.sock"}"\n', ""))
    sign(manifest, TEST_SIGNER)
    command = _one("ExecStart").replace(VENV_WARDEN, str(Path(sys.executable).with_name(
        "warden"))).replace("/etc/warden/cell.toml", str(manifest)).replace(
        "/etc/warden/keys", str(TEST_KEYS))
    env = {**os.environ, "NOTIFY_SOCKET": str(tmp_path / "notify.sock"),
           "RUNTIME_DIRECTORY": str(runtime)}
    process = subprocess.Popen(shlex.split(command), cwd=tmp_path, env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        assert _datagram(receiver, process).startswith(b"READY=1\nSTATUS=held")
        process.terminate()
        _, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
        receiver.sock.close()
    assert process.returncode == 143, err[-2000:]
    assert "stopped while held by SIGTERM: nothing was started or moved" in err
    assert "Traceback" not in err
    assert not list(tmp_path.glob("runs/*")) and not (runtime / "operator.sock").exists()
