"""`warden trial`: each bound of the envelope doing its work, where the trial's manifest came
from, and how a human confirms it (or does not).

Fast tests run the manifest `load_trial` returns on the in-process plant's virtual clock (the
same core, built from the same scaled sections); the slow ones run real `warden trial` and
`warden safety` processes against the emulated UR controller, as tests/cell/test_trial.py does.
"""

from __future__ import annotations

import asyncio
import dataclasses
import hashlib
import io
import itertools
import json
import os
import pty
import signal
import socket
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest

from kernel import provenance
from kernel.app import trial as trial_module
from kernel.app.lockstep import run_lockstep
from kernel.app.session import control_config
from kernel.app.trial import load_trial
from kernel.app.trial_card import trial_card
from kernel.cli_operator import send
from kernel.cli_trial import _confirmed
from kernel.core.runtime import Core
from kernel.manifest import Manifest, ManifestError, load_manifest
from kernel.settings import ClockKind
from kernel.signing import sign
from stubs.fault_control import inject
from stubs.ur_controller.launch import EmulatedController
from tests.cell.test_operator import _as_nobody
from tests.cell.test_trial import (
    ROOT,
    TEST_KEY_ID,
    TEST_KEYS,
    TEST_SIGNER,
    TRIAL,
    _git_head,
    _ur_trial,
    trial_manifest,
    watched_trial,
)
from tests.safety.support import Monitor, safety_table, wait_for

SHIPPED_VELOCITY = 3.1416
"""Every joint's velocity limit in the shipped sim-ur5e manifests."""
AT_REST_RAD_S = 0.01
RUNTIME_STOPPED = 1


def _signed_sim_trial(tmp: Path, cycles: int = 1, cycle_timeout_s: float = 30.0,
                      **envelope: Any) -> Path:
    """The in-process sim-ur5e cell as a signed trial of ``cycles`` cycles (each within
    ``cycle_timeout_s``), with a safety monitor's table, ``envelope`` replacing [trial] keys."""
    trial = TRIAL
    for key, value in envelope.items():
        old = next(line for line in trial.splitlines() if line.startswith(f"{key} = "))
        trial = trial.replace(old, f"{key} = {value}")
    manifest = trial_manifest(tmp, trial=trial, extra=safety_table(tmp))
    manifest.write_text(manifest.read_text().replace(
        "cycles = 1\nsimulated_operator", f"cycles = {cycles}\nsimulated_operator", 1).replace(
        "cycle_timeout_s = 30.0", f"cycle_timeout_s = {cycle_timeout_s}", 1))
    sign(manifest, TEST_SIGNER)
    return manifest


def _lockstep(manifest: Manifest, journal_dir: Path, *, first_tick_only: bool = False,
              ) -> tuple[dict[str, Any], list[dict]]:
    """The trial's manifest on the virtual clock: its summary and its journal's lines;
    ``first_tick_only``: the run ended after its first tick, for a test of the journal's head."""
    virtual = dataclasses.replace(manifest, cell=msgspec.structs.replace(manifest.cell,
                                                                     clock=ClockKind.VIRTUAL))
    hook = (lambda _: True) if first_tick_only else None
    summary = asyncio.run(run_lockstep(virtual, journal_dir, hook=hook))
    (journal,) = journal_dir.glob("*/journal.jsonl")
    return summary, [json.loads(line) for line in journal.read_text().splitlines()]


# -- speed_scale, max_cycles: what the core and the cell are given --------------------------------

def test_speed_scale_scales_the_limits_the_core_and_the_driver_use(tmp_path: Path) -> None:
    scale = 0.1  # 0.31 rad/s: the unscaled moves reach 1.6 rad/s, the contact law 0.39
    manifest = load_trial(_signed_sim_trial(tmp_path, speed_scale=scale), TEST_KEYS)
    scaled = scale * SHIPPED_VELOCITY
    core = Core(manifest.core)
    arm = core.config.limits.arm_mask
    assert np.allclose(core.config.limits.velocity[arm], scaled)
    assert np.allclose(core.planner_limits.velocity, scaled)
    assert np.allclose(control_config(core.config).v_max, scaled)  # the driver's
    summary, lines = _lockstep(manifest, tmp_path / "runs")
    assert summary["cycles"]["verified"] == 1
    assert np.allclose(lines[0]["robot"]["velocity_limits"], scaled)  # what replay rebuilds
    commands = [line for line in lines[1:]
                if line["kind"] == "command" and "q" in line["effect"]]
    fastest = 0.0
    for before, after in itertools.pairwise(commands):  # the contact law's targets too
        dt_s = (after["t"] - before["t"]) / 1000.0
        speed = np.abs(np.subtract(after["effect"]["q"], before["effect"]["q"])) / dt_s
        fastest = max(fastest, float(speed.max()))
    assert fastest <= scaled * (1 + 1e-9), fastest
    assert fastest > 0.9 * scaled  # the scaled limit is what bounded the moves


def test_max_cycles_caps_the_cells_cycles(tmp_path: Path) -> None:
    path = _signed_sim_trial(tmp_path, cycles=3, max_cycles=2, speed_scale=1.0)
    assert load_manifest(path).cell.cycles == 3  # the cell alone would run three
    with pytest.raises(ManifestError, match=r"trial.speed_scale: 1 reduces nothing"):
        load_trial(path, TEST_KEYS)  # the manifest's own speeds: only with --full-speed
    manifest = load_trial(path, TEST_KEYS, full_speed=True)
    assert manifest.cell.cycles == 2
    card = trial_card(manifest, tmp_path / "operator.sock", "monitor", tmp_path / "runs")
    assert "at most 2" in card.splitlines()[1]
    assert "NOT reduced" in card.splitlines()[3], card
    summary, _ = _lockstep(manifest, tmp_path / "runs")
    assert summary["cycles"]["attempted"] == 2 and summary["cycles"]["verified"] == 2


# -- read once: the bytes parsed (and digested) are the bytes verified ---------------------------

def test_the_bytes_parsed_are_the_bytes_verified(tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """The file is replaced the instant its signature has verified (a swap racing the load):
    the trial still runs, and reports the digest of, the bytes that verified."""
    path = _signed_sim_trial(tmp_path, speed_scale=0.5)
    signed = path.read_bytes()
    verify = trial_module.signing.verify

    def verify_then_swap(manifest: Path, keys: Path):  # type: ignore[no-untyped-def]
        verified = verify(manifest, keys)
        path.write_bytes(signed.replace(b"speed_scale = 0.5", b"speed_scale = 1.0"))
        return verified

    monkeypatch.setattr(trial_module.signing, "verify", verify_then_swap)
    manifest = load_trial(path, TEST_KEYS)
    assert path.read_bytes() != signed
    assert manifest.trial is not None and manifest.trial.speed_scale == 0.5
    assert manifest.digest == hashlib.sha256(signed).hexdigest()
    assert manifest.signer == TEST_KEY_ID
    # Nothing after the load reads the file again: the run is the verified manifest's (its
    # journal's head says which; one tick writes it).
    _, lines = _lockstep(manifest, tmp_path / "runs", first_tick_only=True)
    assert lines[0]["provenance"]["manifest"]["sha256"] == hashlib.sha256(signed).hexdigest()
    assert np.allclose(lines[0]["robot"]["velocity_limits"], 0.5 * SHIPPED_VELOCITY)


# -- provenance: software revision and host ------------------------------------------------------

def test_provenance_names_the_revision_and_the_host(tmp_path: Path) -> None:
    before = _git_head()
    record = provenance.provenance("ab" * 32, tmp_path / "cell.toml", TEST_KEY_ID)
    after = _git_head()  # others may commit to this checkout meanwhile
    assert record["software"]["revision"] in {before, after}
    assert record["host"] == socket.gethostname()
    assert record["manifest"]["sha256"] == "ab" * 32 and record["signer"] == TEST_KEY_ID


def test_the_revision_of_a_branch_a_packed_ref_a_detached_head_and_a_worktree(
        tmp_path: Path) -> None:
    a, b, c = "a" * 40, "b" * 40, "c" * 40
    repo = tmp_path / "repo"
    git = repo / ".git"
    (git / "refs" / "heads").mkdir(parents=True)
    (git / "HEAD").write_text("ref: refs/heads/main\n")
    (git / "refs" / "heads" / "main").write_text(a + "\n")
    assert provenance.revision(repo) == a
    (git / "refs" / "heads" / "main").unlink()
    (git / "packed-refs").write_text(f"# pack-refs with: peeled\n{b} refs/heads/main\n")
    assert provenance.revision(repo) == b
    # A linked worktree: .git is a file; HEAD in its own directory, branches in the common one.
    worktree = tmp_path / "wt"
    own = git / "worktrees" / "wt"
    own.mkdir(parents=True)
    worktree.mkdir()
    (worktree / ".git").write_text(f"gitdir: {own}\n")
    (own / "commondir").write_text("../..\n")
    (own / "HEAD").write_text("ref: refs/heads/main\n")
    assert provenance.revision(worktree) == b
    (own / "HEAD").write_text(c + "\n")  # detached
    assert provenance.revision(worktree) == c
    assert provenance.revision(tmp_path / "nothing") == "unknown"


# -- confirmation over the socket: only a member of the operator group ---------------------------

@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to act as another user")
def test_a_confirmation_from_outside_the_operator_group_is_refused(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    runtime = Path(tempfile.mkdtemp(prefix="warden-trial-"))  # a directory nobody may enter
    runtime.chmod(0o755)
    path = trial_manifest(tmp_path)  # [operator] group = "root"
    path.write_text(path.read_text().replace(str(tmp_path / "operator.sock"),
                                             str(runtime / "operator.sock")))
    sign(path, TEST_SIGNER)
    manifest = load_trial(path, TEST_KEYS)
    sock = runtime / "operator.sock"
    monkeypatch.setattr(sys, "stdin", io.StringIO())  # no terminal: the socket is the way
    outcome: dict[str, Any] = {}

    def wait() -> None:
        try:
            outcome["uid"] = _confirmed(manifest, sock, 30.0)
        except ManifestError as error:
            outcome["error"] = error

    waiter = threading.Thread(target=wait)
    waiter.start()
    try:
        wait_for(sock.is_socket, "the trial's operator socket")
        assert _as_nobody(sock, "confirm") == {"error": "PermissionError"}  # 0660, group root
        sock.chmod(0o666)
        refused = _as_nobody(sock, "confirm")  # ...and even so, the credentials are checked
        assert refused["ok"] is False and "is not in group root" in refused["error"], refused
        assert send(str(sock), "status", 5.0)["mode"] == "awaiting confirmation"
        assert waiter.is_alive()  # still waiting: the refused confirmation did not count
        assert send(str(sock), "confirm", 5.0)["ok"]
    finally:
        waiter.join(timeout=30)
        sock.unlink(missing_ok=True)
        runtime.rmdir()
    assert outcome == {"uid": 0}  # root's confirmation, not nobody's, started it


def test_nobody_confirming_in_time_starts_nothing(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    manifest = load_trial(_signed_sim_trial(tmp_path), TEST_KEYS)
    monkeypatch.setattr(sys, "stdin", io.StringIO())
    with pytest.raises(ManifestError, match=r"trial: nobody confirmed within 0.3 s"):
        _confirmed(manifest, tmp_path / "operator.sock", 0.3)
    assert not (tmp_path / "operator.sock").exists()


# -- against the emulated UR controller and a running safety monitor -----------------------------

@pytest.fixture
def kinematic_emulator() -> Iterator[EmulatedController]:
    """The UR controller without MuJoCo (half the CPU of one with it): the arm moves as
    commanded, a cycle's insertion does not verify, for a trial that verifies no cycle."""
    with EmulatedController(plant="kinematic") as controller:
        yield controller


class _AtTerminal:
    """``warden trial`` with a terminal (a pty) on stdin: it asks for the run's name there."""

    def __init__(self, manifest: Path, tmp: Path) -> None:
        self.master, terminal = pty.openpty()
        try:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "kernel.cli", "trial", str(manifest), "--keys",
                 str(TEST_KEYS), "--journal-dir", str(tmp / "runs"), "--json", "-",
                 "--log-format", "json"],
                cwd=ROOT, stdin=terminal, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                text=True)
        finally:
            os.close(terminal)

    def type(self, keys: str) -> None:
        """What the human types (the terminal holds it until the prompt reads it)."""
        os.write(self.master, keys.encode())

    def finish(self, timeout_s: float = 120) -> tuple[int, str, str]:
        out, err = self.process.communicate(timeout=timeout_s)
        return self.process.returncode, out, err

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.communicate()
        os.close(self.master)


def _control(emulator: EmulatedController, query: str) -> dict[str, Any]:
    return inject((emulator.host, int(emulator.info["control_port"])), query)


def _at_rest(emulator: EmulatedController) -> bool:
    return max(map(abs, _control(emulator, "ground_truth")["qd"])) < AT_REST_RAD_S


@pytest.mark.slow
def test_not_confirmed_at_the_terminal_starts_nothing(
        tmp_path: Path, kinematic_emulator: EmulatedController) -> None:
    emulator = kinematic_emulator  # nothing is to move, and nothing does
    manifest = _ur_trial(tmp_path, emulator)
    monitor = Monitor(manifest, tmp_path)
    results = []
    try:
        monitor.wait_watching()
        for keys in ("no\n", "\x04"):  # another answer; Ctrl-D (end of input)
            terminal = _AtTerminal(manifest, tmp_path)
            try:
                terminal.type(keys)
                results.append(terminal.finish())
            finally:
                terminal.close()
        heartbeat = monitor.status()["heartbeat"]
    finally:
        monitor.stop()
    for code, out, err in results:
        assert code == 2, err[-3000:]
        assert "Traceback" not in err
        assert "type sim-ur5e-rtde to start the trial" in err and "stop: operator" in err
        assert err.strip().splitlines()[-1].endswith("trial: not confirmed at the terminal")
        assert out == ""
    assert not list(tmp_path.glob("runs/*")), "a trial nobody confirmed wrote a journal"
    assert _control(emulator, "motion")["motion_commands"] == 0
    assert heartbeat["pid"] is None  # no warden loop ever ran


@pytest.mark.slow
def test_confirmed_at_the_terminal_the_trial_ends_when_its_duration_is_up(
        tmp_path: Path, kinematic_emulator: EmulatedController) -> None:
    emulator = kinematic_emulator  # the trial ends in its first cycle, verifying nothing
    manifest = _ur_trial(tmp_path, emulator, trial=TRIAL.replace("max_duration_s = 60.0",
                                                                 "max_duration_s = 1.0"))
    monitor = Monitor(manifest, tmp_path)
    terminal: _AtTerminal | None = None
    try:
        monitor.wait_watching()
        terminal = _AtTerminal(manifest, tmp_path)
        terminal.type("sim-ur5e-rtde\n")
        code, out, err = terminal.finish()
        wait_for(lambda: _at_rest(emulator), "the arm at rest", timeout_s=5)
        stops = monitor.status()["stops"]
    finally:
        if terminal is not None:
            terminal.close()
        monitor.stop()
    assert code == 1, err[-3000:]
    summary = json.loads(out)  # stdout is the summary alone: the prompt went to stderr
    assert summary["trial"]["ended"] == ("ended: the trial's duration is up (1 s); 0 of 1 "
                                         "cycles verified, cycle 1 unfinished")
    assert summary["trial"]["cycles"]["unfinished"] == 1  # the cycle it stopped is counted
    assert summary["trial"]["confirmed_by_uid"] == os.getuid()
    assert summary["cycles"]["verified"] == 0  # a cycle takes several seconds
    assert stops == 0  # warden ended it in order: the monitor had nothing to stop
    assert _control(emulator, "status")["runtime_state"] == RUNTIME_STOPPED  # script stopped
    (journal,) = (tmp_path / "runs").glob("*/journal.jsonl")
    records = [json.loads(line) for line in journal.read_text().splitlines()[1:]]
    ticks = [record["t"] for record in records if record["kind"] == "tick"]
    # The bound reads the run's clock (the journal's, ms, from before the device's bring-up,
    # which may take longer than 1 s here) after each tick: the trial ended at the first tick
    # that saw 1 s reached, not one later.
    assert ticks and all(t < 1000 for t in ticks[:-1]), ticks[-3:]
    assert "trial sim-ur5e-rtde: ended: the trial's duration is up" in err


@pytest.mark.slow
def test_the_monitor_no_longer_taking_the_heartbeat_ends_the_trial(
        tmp_path: Path, kinematic_emulator: EmulatedController) -> None:
    emulator = kinematic_emulator  # the trial ends in its first cycle, verifying nothing
    manifest = _ur_trial(tmp_path, emulator)
    with watched_trial(manifest, tmp_path) as (monitor, trial):
        trial.confirm()
        wait_for(lambda: monitor.status()["heartbeat"]["state"] == "alive",
                 "warden's heartbeat at the monitor")
        monitor.process.send_signal(signal.SIGSTOP)  # alive, but no longer draining its socket
        try:
            code, summary, err = trial.finish()
        finally:
            monitor.process.send_signal(signal.SIGCONT)
        wait_for(lambda: _at_rest(emulator), "the arm at rest", timeout_s=5)
    assert code == 1, err[-3000:]
    ended = summary["trial"]["ended"]
    assert "the safety monitor stopped taking warden's heartbeat (EAGAIN)" in ended, ended
    assert summary["cycles"]["verified"] == 0
    assert summary["safety"]["failed"] > 0
