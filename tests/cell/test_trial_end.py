"""`warden trial` tells how it ended: an interrupted, stuck or bound-ended trial exits 1, and
its summary, table and last line count the cycle under way as unfinished and the rest as never
started (tests/cell/test_trial_envelope.py has the helpers)."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgspec
import pytest

from kernel.app.trial import TrialBound, cycle_count, load_trial, verdict
from kernel.cli_operator import send
from kernel.signing import sign
from stubs.ur_controller.launch import EmulatedController
from tests.cell.operator_at_hand import operator_at_hand
from tests.cell.test_trial import TEST_KEYS, TEST_SIGNER, TRIAL, _ur_trial
from tests.cell.test_trial_envelope import _at_rest, _AtTerminal, _lockstep, _signed_sim_trial
from tests.safety.support import Monitor, wait_for


def test_a_trial_out_of_time_counts_its_unfinished_cycle(tmp_path: Path) -> None:
    """A cycle that cannot finish within the run's time budget (cycles x cycle_timeout_s, a
    cycle here takes several seconds): the trial fails, saying it timed out, and counts the
    cycle under way as unfinished and the next as never started (it used to say "0 of 0")."""
    path = _signed_sim_trial(tmp_path, cycles=2, cycle_timeout_s=1.0, max_cycles=2)
    manifest = load_trial(path, TEST_KEYS)
    summary, _ = _lockstep(manifest, tmp_path / "runs")
    assert summary["timed_out"] and summary["cycles"]["verified"] == 0
    code, why = verdict(summary, TrialBound(60.0), manifest.cell.cycles)
    assert code == 1
    assert why == ("ended: timed out: the run's time budget (cycles x cell.cycle_timeout_s) "
                   "ran out; 0 of 2 cycles verified, cycle 1 unfinished, 1 not started"), why
    # The run lists the cycle it cut short (``cycle_cut_short``); a summary that lists only
    # the finished cycles (no ``cycle_cut_short``) is counted the same.
    assert summary["cycle_cut_short"] == 1
    unlisted = {key: value for key, value in summary.items() if key != "cycle_cut_short"}
    unlisted["cycles"] = {**summary["cycles"], "detail": summary["cycles"]["detail"][:-1]}
    assert cycle_count(summary, 2) == cycle_count(unlisted, 2) == {
        "planned": 2, "finished": 0, "verified": 0, "unfinished": 1, "not_started": 1}


@pytest.mark.slow
def test_a_trial_interrupted_in_cycle_2_of_3_counts_its_unfinished_cycle(tmp_path: Path) -> None:
    """SIGINT once cycle 1 has verified, on the in-process cell on the wall clock (the trial's
    own run, `run_wall`): the trial fails, saying it was interrupted, with cycle 2 counted as
    unfinished and cycle 3 as never started (it used to exit 0: "1 of 1 cycles verified")."""
    from kernel.cli_run import run_wall

    trial = load_trial(_signed_sim_trial(tmp_path, cycles=3, max_cycles=3), TEST_KEYS)
    # The simulated operator stands in for the human who would accept a recovery (a policy
    # server late on a loaded machine holds the arm in SAFE_HOLD): this test is about the end.
    manifest = dataclasses.replace(trial, cell=msgspec.structs.replace(trial.cell,
                                                                   simulated_operator=True))
    sent: list[int] = []

    def interrupt_in_cycle_2(context: Any) -> bool:
        if context.cell.controller.results and not sent:
            sent.append(len(context.cell.controller.results))
            os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C: the run's handler holds the arm
        return False

    summary = run_wall(manifest, tmp_path / "runs", interrupt_in_cycle_2)
    assert sent == [1] and summary["stopped"]
    code, why = verdict(summary, TrialBound(60.0), manifest.cell.cycles)
    assert code == 1
    verified = summary["cycles"]["verified"]
    caught = summary.get("interrupted") or "SIGINT or SIGTERM"  # which, where the run says
    assert why == (f"ended: interrupted ({caught}): the arm was held and the device "
                   f"closed; {verified} of 3 cycles verified, cycle 2 unfinished, 1 not started")


@pytest.fixture
def kinematic_emulator() -> Iterator[EmulatedController]:
    """The UR emulator without MuJoCo: a fraction of the CPU, where a cycle's insertion does
    not verify but the cycle still ends, and the next one starts."""
    with EmulatedController(plant="kinematic") as controller:
        yield controller


@pytest.mark.slow
def test_the_walk_through_at_a_terminal_interrupted_in_cycle_2_of_3(
        tmp_path: Path, kinematic_emulator: EmulatedController) -> None:
    """docs/operations.md 11's walk-through as written: no ``[operator] socket`` in the
    manifest, no service running (so no /run/warden), the run's name typed at a terminal. The
    trial serves its socket where the card says (it used to exit 2 once confirmed: it wanted
    /run/warden), and Ctrl-C (SIGINT) in cycle 2 of 3 ends it non-zero with the unfinished
    cycle counted (it used to exit 0, "1 of 1 cycles verified")."""
    manifest = _ur_trial(tmp_path, kinematic_emulator, trial=TRIAL.replace("max_cycles = 1",
                                                                 "max_cycles = 3"))
    text = manifest.read_text().replace("cycles = 1\nsimulated_operator",
                                        "cycles = 3\nsimulated_operator", 1)
    configured = f'\n[operator]\nsocket = "{tmp_path / "operator.sock"}"\n'
    assert configured in text
    manifest.write_text(text.replace(configured, "\n"))
    sign(manifest, TEST_SIGNER)
    monitor = Monitor(manifest, tmp_path)
    terminal: _AtTerminal | None = None
    try:
        monitor.wait_watching()
        terminal = _AtTerminal(manifest, tmp_path)
        terminal.type("sim-ur5e-rtde\n")
        process = terminal.process
        sock = _card_socket(tmp_path, process)
        err: list[str] = []  # read as it comes: a full pipe would block warden's log lines
        drain = threading.Thread(target=lambda: err.extend(process.stderr or ()))
        drain.start()
        with operator_at_hand(sock, lambda: _at_rest(kinematic_emulator)) as recovered:
            wait_for(lambda: process.poll() is not None or _cycle(sock) >= 2,
                     "cycle 2 under way", timeout_s=120)
        print(f"recovered from: {recovered or 'no fallback'}")
        process.send_signal(signal.SIGINT)
        out = process.stdout.read() if process.stdout else ""
        code = process.wait(timeout=120)
        drain.join(timeout=30)
        wait_for(lambda: _at_rest(kinematic_emulator), "the arm at rest", timeout_s=5)
    finally:
        if terminal is not None:
            terminal.close()
        monitor.stop()
    assert code == 1, "".join(err)[-3000:]
    trial = json.loads(out)["trial"]
    verified = json.loads(out)["cycles"]["verified"]  # 0 on the kinematic plant
    assert trial["cycles"] == {"planned": 3, "finished": 1, "verified": verified,
                               "unfinished": 1, "not_started": 1}, trial
    assert trial["ended"].startswith("ended: interrupted (SIGINT"), trial
    assert trial["ended"].endswith(f"{verified} of 3 cycles verified, cycle 2 unfinished, 1 not "
                                   "started"), trial
    assert trial["operator_socket"] == str(sock)
    if sock.parent == Path("/run/warden"):  # there and free (a host that ran the service):
        assert not sock.exists()  # the trial served the default socket and removed it
    else:
        assert not sock.parent.exists()  # the directory the trial made for its socket is gone


def _card_socket(tmp: Path, process: subprocess.Popen[str]) -> Path:
    """The operator socket the card names (read from the trial's stderr as it comes)."""
    assert process.stderr is not None
    for line in process.stderr:
        if line.startswith("stop: operator"):
            return Path(line.split("--socket ", 1)[1].split(":", 1)[0])
    raise AssertionError(f"no card: the trial exited {process.wait()}")


def _cycle(sock: Path) -> int:
    try:
        return int(send(str(sock), "status", 2.0).get("cycle") or 0)
    except (OSError, ValueError):
        return 0  # not served yet (the device is still being brought up)
