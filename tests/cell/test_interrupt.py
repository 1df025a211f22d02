"""Ctrl-C and SIGTERM end a ``warden run`` in order (kernel/app/interrupt.py).

The simulated cell runs as a process of its own, as from a terminal or under systemd. Ctrl-C is
SIGINT to the whole process group (what a terminal sends); ``systemctl stop`` is SIGTERM to
warden alone (``KillMode=mixed``). Either, mid-cycle: exit 130 or 143, no traceback from warden
or any child, stderr says the run was interrupted and the arm held, the summary counts the cycle
under way as attempted and not verified, the journal replays identically, and no child is left.
A start that is refused, or stopped before the first tick, leaves no run directory, or one that
``warden replay`` reads.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from kernel.cli import main
from tests.cell.harness import MANIFESTS, replays_identically, run_dir
from tests.net import process_tree

pytestmark = pytest.mark.slow
ROOT = MANIFESTS.parent
TIMEOUT_S = 120.0


def _cell(tmp_path: Path) -> Path:
    """The simulated cell, with an operator socket of its own (the default one may be another
    warden's on this host)."""
    path = tmp_path / "sim-ur5e.toml"
    path.write_text((MANIFESTS / "sim-ur5e.toml").read_text()
                    + f'\n[operator]\nsocket = "{tmp_path / "operator.sock"}"\n')
    return path


def _start(tmp_path: Path, manifest: Path, cycles: int = 2,
           *extra: str) -> subprocess.Popen[bytes]:
    """`warden run` in a session of its own, as a terminal's foreground job is a group."""
    return subprocess.Popen(
        [sys.executable, "-m", "kernel.cli", "run", str(manifest), "--cycles", str(cycles),
         "--journal-dir", str(tmp_path / "runs"), "--json", str(tmp_path / "summary.json"),
         "--log-format", "json", *extra],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=(tmp_path / "stderr").open("wb"),
        start_new_session=True)


def _wait_for(warden: subprocess.Popen[bytes], done: object, what: str) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while not done():  # type: ignore[operator]
        assert warden.poll() is None, f"warden ended ({warden.returncode}) before {what}"
        assert time.monotonic() < deadline, f"no {what} within {TIMEOUT_S} s"
        time.sleep(0.05)


def _reached(stderr: Path, cycle: int, step: str) -> bool:
    """The run's JSON progress (--log-format json) says ``cycle`` is at ``step``."""
    for line in stderr.read_bytes().splitlines():
        try:
            entry = json.loads(line)
        except ValueError:
            continue
        if isinstance(entry, dict) and entry.get("event") == "progress" and (
                entry.get("cycle"), entry.get("step")) == (cycle, step):
            return True
    return False


def _ended(pids: set[int]) -> bool:
    return all(not Path(f"/proc/{pid}").exists() for pid in pids)


@pytest.mark.parametrize(("signum", "group", "code", "cycles"), [
    (signal.SIGINT, True, 130, 2),  # Ctrl-C at a terminal: the whole process group
    # systemctl stop (KillMode=mixed): warden alone. In the first cycle of one: the count of a
    # finished cycle beside the cut one is the Ctrl-C case's, and a cycle less is seconds less.
    (signal.SIGTERM, False, 143, 1),
])
def test_a_signal_mid_cycle_ends_the_run_holding_the_arm(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], signum: signal.Signals,
        group: bool, code: int, cycles: int) -> None:
    warden = _start(tmp_path, _cell(tmp_path), cycles)
    stderr = tmp_path / "stderr"
    try:
        _wait_for(warden, lambda: _reached(stderr, cycles, "pick approach"),
                  f"cycle {cycles} under way")
        children = process_tree(warden.pid) - {warden.pid}
        assert children, "the cell's children (job worker, policy server) are running"
        if group:
            os.killpg(warden.pid, signum)
        else:
            warden.send_signal(signum)
        assert warden.wait(timeout=TIMEOUT_S) == code
    finally:
        if warden.poll() is None:
            os.killpg(warden.pid, signal.SIGKILL)
            warden.wait()
    deadline = time.monotonic() + 10.0
    while not _ended(children) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _ended(children), "warden ended its children"
    err = stderr.read_text()
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert (f"warden: interrupted by {signum.name} during cycle {cycles} of {cycles}; the run "
            "ended there: the arm was held and the device closed") in err, err
    summary = json.loads((tmp_path / "summary.json").read_text())
    directory = run_dir(tmp_path / "runs")
    assert json.loads((directory / "summary.json").read_text())["cycles"] == summary["cycles"]
    assert summary["interrupted"] == signum.name and summary["stopped"]
    assert summary["cycle_cut_short"] == cycles
    detail = summary["cycles"]["detail"]
    *finished, cut = detail
    assert len(detail) == summary["cycles"]["attempted"] == cycles
    assert summary["cycles"]["verified"] == sum(int(cycle["verified"]) for cycle in finished)
    assert (cut["index"], cut["verified"], cut["reason"]) == (
        cycles, False, f"interrupted by {signum.name}")
    assert (f"{summary['cycles']['verified']} of {cycles} cycles attempted were verified"
            in err)
    assert replays_identically(directory)
    capsys.readouterr()
    assert main(["replay", str(directory / "journal.jsonl")]) == 0
    assert "identical" in capsys.readouterr().err


def test_ctrl_c_ends_a_lockstep_run_in_order(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """The virtual clock's loop never yields to the event loop: the signal still reaches it."""
    warden = _start(tmp_path, _cell(tmp_path), 50, "--clock", "virtual")
    try:
        # The first step of cycle 1: the loop is spinning (the signal does not need a later
        # step, and each step of the virtual clock's cycle is CPU seconds on a loaded machine).
        _wait_for(warden, lambda: _reached(tmp_path / "stderr", 1, "pick approach"),
                  "cycle 1 under way")
        os.killpg(warden.pid, signal.SIGINT)
        assert warden.wait(timeout=TIMEOUT_S) == 130
    finally:
        if warden.poll() is None:
            os.killpg(warden.pid, signal.SIGKILL)
            warden.wait()
    err = (tmp_path / "stderr").read_text()
    summary = json.loads((tmp_path / "summary.json").read_text())
    cut = summary["cycle_cut_short"]
    assert "Traceback" not in err and f"interrupted by SIGINT during cycle {cut} of 50" in err
    cycles = summary["cycles"]
    assert cycles["attempted"] == cut >= 1 and cycles["detail"][-1]["reason"] == (
        "interrupted by SIGINT")
    assert replays_identically(run_dir(tmp_path / "runs"))


def test_a_stop_during_start_up_leaves_no_run_directory_or_one_that_replays(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    warden = _start(tmp_path, _cell(tmp_path), cycles=1)
    try:
        _wait_for(warden, lambda: any((tmp_path / "runs").glob("*/journal.jsonl")),
                  "the run's directory")
        warden.send_signal(signal.SIGTERM)
        assert warden.wait(timeout=TIMEOUT_S) == 143
    finally:
        if warden.poll() is None:
            os.killpg(warden.pid, signal.SIGKILL)
            warden.wait()
    err = (tmp_path / "stderr").read_text()
    assert "Traceback" not in err and "warden: interrupted by SIGTERM" in err, err
    left = list((tmp_path / "runs").iterdir())
    if "before the first tick; the run ended there: nothing moved" in err:
        assert left == [] and "no run directory kept" in err
    else:  # the signal came after the first tick: a run, interrupted, whose journal replays
        (directory,) = left
        assert main(["replay", str(directory / "journal.jsonl")]) == 0, capsys.readouterr().err


def test_a_refused_start_leaves_no_run_directory(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """The device is not there: found at bring-up, after the run's directory was made."""
    text = (MANIFESTS / "sim-ur5e-rtde.toml").read_text()
    text = text.replace('name = "ur_rtde"', 'name = "ur_rtde"\nhost = "127.0.0.9"\n'
                        'connect_timeout_s = 0.5\nreconnect_attempts = 0', 1)
    text = text.replace('plant = "mujoco"', "launch = false", 1)
    text = text.replace("cycle_timeout_s = 30.0", "cycle_timeout_s = 30.0\n"
                        "simulated_operator = false", 1)
    text += f'\n[operator]\nsocket = "{tmp_path / "operator.sock"}"\ngroup = "root"\n'
    path = tmp_path / "cell.toml"
    path.write_text(text)
    runs = tmp_path / "runs"
    assert main(["run", str(path), "--journal-dir", str(runs)]) == 2
    assert "127.0.0.9" in capsys.readouterr().err
    assert list(runs.iterdir()) == []
