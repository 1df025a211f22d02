"""manifests/warden.service: the settings the runtime relies on, and systemd's own verdict."""

from __future__ import annotations

import argparse
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

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
