"""manifests/warden-safety.service: the monitor's unit beside warden's, and systemd's verdict."""

from __future__ import annotations

import argparse
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from kernel import cli_run, cli_safety, signing
from kernel.safety.service import PRIORITY
from kernel.safety.settings import DEFAULT_DIRECTORY

ROOT = Path(__file__).resolve().parents[2]
UNIT = ROOT / "manifests" / "warden-safety.service"
WARDEN_UNIT = ROOT / "manifests" / "warden.service"
VENV_WARDEN = "/opt/warden/.venv/bin/warden"


def _settings(unit: Path) -> dict[str, list[str]]:
    found: dict[str, list[str]] = {}
    for line in unit.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith(("#", ";", "[")):
            continue
        key, _, value = line.partition("=")
        found.setdefault(key, []).append(value)
    return found


def _one(key: str, unit: Path = UNIT) -> str:
    values = _settings(unit)[key]
    assert len(values) == 1, (key, values)
    return values[0]


def test_it_is_up_and_watching_before_warden_and_warden_needs_it() -> None:
    assert _one("Type") == "notify" and _one("NotifyAccess") == "main"
    assert "warden.service" in _one("Before").split()
    assert "warden.service" in _one("RequiredBy").split()
    # Its own watchdog is shorter than warden's: it is the process that must not hang.
    assert 0 < int(_one("WatchdogSec")) < int(_one("WatchdogSec", WARDEN_UNIT))


def test_a_device_that_is_not_up_yet_is_retried() -> None:
    assert _one("Restart") == "on-failure"  # exit 2 included: no RestartPreventExitStatus
    assert "RestartPreventExitStatus" not in _settings(UNIT)
    assert int(_one("StartLimitBurst")) >= 1 and int(_one("StartLimitIntervalSec")) > 0


def test_its_own_user_in_wardens_group() -> None:
    assert _one("User") not in ("", "root", _one("User", WARDEN_UNIT))
    assert _one("Group") == _one("Group", WARDEN_UNIT)
    assert f"/run/{_one('RuntimeDirectory')}" == DEFAULT_DIRECTORY  # where its sockets go
    assert int(_one("OOMScoreAdjust")) < int(_one("OOMScoreAdjust", WARDEN_UNIT))


def test_its_loop_may_outrank_wardens() -> None:
    assert int(_one("LimitRTPRIO")) >= PRIORITY > 50  # warden's loop asks for 50
    assert set(_one("AmbientCapabilities").split()) == {"CAP_SYS_NICE", "CAP_IPC_LOCK"}
    for hardening in ("NoNewPrivileges", "ProtectHome", "PrivateTmp"):
        assert _one(hardening) == "yes"
    assert _one("ProtectSystem") == "strict" and _one("DevicePolicy") == "closed"


def test_commands_parse_and_name_wardens_manifest() -> None:
    parser = argparse.ArgumentParser(prog="warden")
    commands = parser.add_subparsers(dest="command", required=True)
    cli_safety.add_commands(commands)
    cli_run.add_commands(commands)
    signing.add_commands(commands)
    start = shlex.split(_one("ExecStart"))
    assert start[0] == VENV_WARDEN
    run = parser.parse_args(start[1:])
    assert run.handler is cli_safety.safety_command
    wardens = parser.parse_args(shlex.split(_one("ExecStart", WARDEN_UNIT))[1:])
    assert run.target == [wardens.manifest]
    assert _one("ExecStartPre") == _one("ExecStartPre", WARDEN_UNIT)


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
def test_systemd_analyze_verify(tmp_path: Path) -> None:
    warden = Path(sys.executable).with_name("warden")
    if not warden.exists():
        pytest.skip("the warden entry point is not installed in this venv")
    copy = tmp_path / "warden-safety.service"
    copy.write_text(UNIT.read_text().replace(VENV_WARDEN, str(warden)))
    done = subprocess.run(["systemd-analyze", "verify", str(copy)], capture_output=True,
                          text=True, timeout=60, check=False)
    assert done.returncode == 0 and "warden-safety.service" not in done.stderr, done.stderr
