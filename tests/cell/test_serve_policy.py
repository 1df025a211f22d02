"""``warden serve-policy``: the reference server a shipped cell expects, run by hand.

A shipped manifest changed to ``[policy] launch = false`` and a fixed port runs its cycle
against a ``warden serve-policy`` the test started on that port, as docs/operations.md
("Running the policy server yourself") tells an operator to do.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from kernel.cli import main
from tests.cell.harness import MANIFESTS, run_dir

ROOT = MANIFESTS.parent


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@contextmanager
def _serve_policy(*args: str) -> Iterator[subprocess.Popen[str]]:
    """``warden serve-policy ARGS`` until it says READY; SIGINT at the end, which it must take
    as an ordinary stop (exit 0, nothing on stderr)."""
    server = subprocess.Popen([sys.executable, "-m", "kernel.cli", "serve-policy", *args],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    try:
        assert server.stdout is not None
        ready = server.stdout.readline()
        assert ready.startswith("READY "), (ready, server.stderr and server.stderr.read())
        yield server
        server.send_signal(signal.SIGINT)
        _, err = server.communicate(timeout=10)
        assert server.returncode == 0 and err == "", err
    finally:
        if server.poll() is None:
            server.kill()
            server.wait()


def test_help_lists_the_options(capsys: pytest.CaptureFixture[str]) -> None:
    """In this process (the CLI's entry point, as `warden serve-policy --help` calls it): a new
    interpreter is seconds of imports on the loaded test machine, and the cell test below
    starts the command as a process."""
    with pytest.raises(SystemExit) as exited:
        main(["serve-policy", "--help"])
    assert exited.value.code == 0
    out = capsys.readouterr().out
    for option in ("--host", "--port", "--expose", "manifest"):
        assert option in out


@pytest.mark.slow
def test_a_cell_with_launch_false_runs_against_a_served_policy(tmp_path: Path) -> None:
    port = _free_port()
    text = (MANIFESTS / "sim-ur5e.toml").read_text()
    for old, new in (("launch = true ", "launch = false"), ("port = 0 ", f"port = {port}")):
        assert text.count(old) == 1
        text = text.replace(old, new)
    # An operator socket of its own: the default one may be another warden's on this host.
    own = tmp_path / "own-server.toml"
    own.write_text(text + f'\n[operator]\nsocket = "{tmp_path / "operator.sock"}"\n')
    with _serve_policy("manifests/sim-ur5e.toml", "--port", str(port)) as server:
        assert server.poll() is None
        code = main(["run", str(own), "--cycles", "1", "--journal-dir", str(tmp_path / "runs")])
    assert code == 0
    summary = json.loads((run_dir(tmp_path / "runs") / "summary.json").read_text())
    assert summary["cycles"]["verified"] == summary["cycles"]["attempted"] == 1
    assert summary["link"]["handshakes_accepted"] >= 1


@pytest.mark.parametrize(("args", "needle"), [
    (["--port", "70000"], "--port: must be 0 to 65535"),
    (["--host", "0.0.0.0"], "--host: '0.0.0.0' is not a loopback address"),
    (["nowhere.toml"], "cannot read file"),
])
def test_bad_options_exit_2_naming_them(args: list[str], needle: str,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["serve-policy", *args]) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err
