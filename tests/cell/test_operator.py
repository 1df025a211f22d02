"""A human's authority from outside the process: the operator socket of a running `warden run`.

The run is a real `warden run` process (the simulated cell, its simulated operator off, so
that only the human recovers); the commands go through `warden operator`'s own client over the
Unix socket, as root (a member of the group) and as `nobody` (not one).
"""

from __future__ import annotations

import json
import os
import pwd
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import pytest

from kernel.cli_operator import send
from tests.cell.harness import MANIFESTS

pytestmark = pytest.mark.slow
ROOT = MANIFESTS.parent


def _manifest(tmp: Path, socket: Path) -> Path:
    text = (MANIFESTS / "sim-ur5e.toml").read_text()
    text = text.replace("cycles = 3", "cycles = 1\nsimulated_operator = false", 1)
    text += f'\n[operator]\nsocket = "{socket}"\ngroup = "root"\n'
    path = tmp / "cell.toml"
    path.write_text(text)
    return path


class _Run:
    def __init__(self, tmp: Path, socket: Path | None = None) -> None:
        self.socket = socket or tmp / "operator.sock"
        self.manifest = _manifest(tmp, self.socket)
        self.process = subprocess.Popen(
            [sys.executable, "-m", "kernel.cli", "run", str(self.manifest),
             "--journal-dir",
             str(tmp / "runs"), "--log-format", "json"], cwd=ROOT,
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 30
        while not self.socket.is_socket():
            if time.monotonic() > deadline or self.process.poll() is not None:
                raise AssertionError(f"no operator socket: {self.stop()[-3000:]}")
            time.sleep(0.05)

    def command(self, command: str) -> dict[str, Any]:
        return send(str(self.socket), command, 5.0)

    def wait_for(self, mode: str) -> dict[str, Any]:
        deadline = time.monotonic() + 10
        while (status := self.command("status"))["mode"] != mode:
            assert time.monotonic() < deadline, status
            time.sleep(0.05)
        return status

    def stop(self) -> str:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        _, err = self.process.communicate(timeout=30)
        return err


def _journal(tmp: Path) -> list[dict[str, Any]]:
    (journal,) = (tmp / "runs").glob("*/journal.jsonl")
    return [json.loads(line) for line in journal.read_text().splitlines()[1:]]


def _cli(command: str, manifest: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """``warden operator COMMAND MANIFEST``: the socket from the manifest; exit code, stderr."""
    from kernel.cli import main

    code = main(["operator", command, str(manifest)])
    return code, capsys.readouterr().err


def test_a_human_takes_over_releases_recovers_stops_and_resets(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = _Run(tmp_path)
    try:
        mode = run.command("status")["mode"]
        # Refused by the core (no e-stop to reset, whatever the run's mode): exit 1 and why.
        code, err = _cli("reset", run.manifest, capsys)
        assert (code, err.startswith("warden: reset: refused: no e-stop to reset in ")) == (
            1, True), err
        assert mode != "E_STOP" and run.command("status")["mode"] != "E_STOP"
        taken = run.command("takeover")
        assert taken["ok"] and taken["took_over"] and 0 < taken["latency_ms"] < 2000
        assert taken["mode"] == "HUMAN_RECOVERY"
        assert run.command("release")["mode"] == "SAFE_HOLD"
        recovered = run.command("accept-recovery")
        assert recovered["ok"]
        assert any(line.get("trigger") == "RECOVERY_ACCEPTED" for line in recovered["lines"])
        assert run.command("stop")["mode"] == "E_STOP"
        assert run.command("reset")["mode"] == "SAFE_HOLD"
        refused = run.command("release")  # nothing to release: refused by the core, with why
        assert refused["ok"] is False and refused["error"] == (
            "refused: no takeover to release in SAFE_HOLD")
        assert any(line.get("accepted") is False for line in refused["lines"])
        assert _cli("reset", run.manifest, capsys)[0] == 1  # no e-stop to reset
        assert _cli("accept-recovery", run.manifest, capsys) == (0, "")
    finally:
        run.stop()
    operator = [e for e in _journal(tmp_path) if e["kind"] == "operator"]
    assert [e["action"] for e in operator] == ["reset", "takeover", "release",
                                               "accept_recovery", "estop", "reset", "release",
                                               "reset", "accept_recovery"]
    assert all(e["uid"] == 0 for e in operator)


def _as_nobody(socket: Path, command: str) -> dict[str, Any]:
    """``command`` sent by the user nobody (a forked child that drops root): the answer, or
    the error its connection met."""
    nobody = pwd.getpwnam("nobody")
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        try:
            os.setgroups([])
            os.setgid(nobody.pw_gid)
            os.setuid(nobody.pw_uid)
            outcome: dict[str, Any] = send(str(socket), command, 5.0)
        except OSError as error:
            outcome = {"error": type(error).__name__}
        os.write(write, json.dumps(outcome).encode())
        os._exit(0)
    os.close(write)
    with os.fdopen(read) as stream:
        outcome = json.loads(stream.read())
    os.waitpid(pid, 0)
    return outcome


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to act as another user")
def test_a_user_outside_the_group_is_refused_twice(tmp_path: Path) -> None:
    runtime = Path(tempfile.mkdtemp(prefix="warden-operator-"))  # a directory nobody may enter
    runtime.chmod(0o755)
    run = _Run(tmp_path, runtime / "operator.sock")
    try:
        # The socket file (0660, group root) keeps nobody out...
        assert _as_nobody(run.socket, "takeover") == {"error": "PermissionError"}
        run.socket.chmod(0o666)
        # ...and even so, the server checks the caller's credentials.
        refused = _as_nobody(run.socket, "takeover")
        assert refused["ok"] is False and "is not in group root" in refused["error"]
        assert run.command("status")["mode"] == "RUNNING"  # nothing moved
    finally:
        err = run.stop()
        shutil.rmtree(runtime, ignore_errors=True)
    assert "operator command refused" in err
    assert not [e for e in _journal(tmp_path) if e["kind"] == "operator"]


def test_no_warden_at_the_socket_exits_2(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    from kernel.cli import main

    assert main(["operator", "status", "--socket", str(tmp_path / "none.sock")]) == 2
    assert "no warden answers here" in capsys.readouterr().err


def test_an_unreadable_manifest_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from kernel.cli import main

    manifest = tmp_path / "cell.toml"
    manifest.write_text((MANIFESTS / "sim-ur5e.toml").read_text() + "\n[operator]\nsocket = 3\n")
    assert main(["operator", "status", str(manifest)]) == 2
    err = capsys.readouterr().err
    assert f"{manifest}: operator.socket" in err and "Traceback" not in err
