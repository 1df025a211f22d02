"""`warden trial`: what it refuses before anything starts, and a confirmed trial inside its
envelope.

Every refusal is a real `warden trial` process on a manifest signed (or not) with the
repository's test-only key; each must exit 2 with a message that names what is wrong, and must
not have started a device, a policy server or a journal.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from kernel.cli_operator import send
from kernel.model_file import BUILTIN
from kernel.robot_model import digest
from kernel.signing import sign
from stubs.ur_controller.launch import EmulatedController
from tests.cell.harness import MANIFESTS
from tests.cell.operator_at_hand import control_of, emulator_at_rest, operator_at_hand
from tests.safety.support import (
    FORCE_LIMIT_N,
    Monitor,
    safety_table,
    ur_manifest,
    wait_for,
)

ROOT = MANIFESTS.parent
TEST_KEYS = MANIFESTS / "keys" / "test-only"
TEST_SIGNER = TEST_KEYS / "test-signer.key"
TEST_KEY_ID = "276bb30aa3b714e0"
UR_DEVICE_TIMEOUT_MS = 1000.0
"""As tests/safety/test_safety_cells.py gives the monitor (the emulator shares two cores)."""
TRIAL = """
[trial]
max_cycles = 1
max_duration_s = 60.0
workspace_lower = [-0.80, -0.40, 0.00]
workspace_upper = [-0.20, 0.35, 0.50]
speed_scale = 0.5
max_wrist_force_n = 150.0
"""
"""150 N, as the safety monitor's tests use: the MuJoCo cell's grasp peaks near 60 N."""


def trial_manifest(tmp: Path, *, trial: str = TRIAL, operator: bool = True,
                   extra: str = "") -> Path:
    """The simulated UR5e cell as a trial: one cycle, a human recovers, its envelope."""
    text = (MANIFESTS / "sim-ur5e.toml").read_text()
    if operator:
        text = text.replace("cycles = 3", "cycles = 1\nsimulated_operator = false", 1)
    text += f'\n[operator]\nsocket = "{tmp / "operator.sock"}"\ngroup = "root"\n'
    text = with_model_digest(text) + trial + extra
    path = tmp / "trial-cell.toml"
    path.write_text(text)
    return path


def with_model_digest(text: str) -> str:
    """A trial's robot section names its model's digest (the signature then covers it)."""
    named = 'kinematics = "ur5e"'
    if named not in text:
        raise ValueError("the manifest does not name the built-in ur5e model")
    return text.replace(named, f'model_sha256 = "{digest(BUILTIN["ur5e"].path)}"\n{named}', 1)


def run_trial(manifest: Path, tmp: Path, *extra: str,
              timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "kernel.cli", "trial", str(manifest), "--keys", str(TEST_KEYS),
         "--journal-dir", str(tmp / "runs"), "--log-format", "json", *extra],
        cwd=ROOT, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL,
        check=False)


def _refused(done: subprocess.CompletedProcess[str], tmp: Path, *words: str) -> str:
    message = done.stderr.strip().splitlines()[-1] if done.stderr.strip() else ""
    assert done.returncode == 2, done.stderr[-2000:]
    for word in words:
        assert word in message, message
    assert "Traceback" not in done.stderr
    assert not list(tmp.glob("runs/*")), "a refused trial wrote a journal"
    return message


def test_unsigned_manifest_is_refused(tmp_path: Path) -> None:
    done = run_trial(trial_manifest(tmp_path), tmp_path)
    _refused(done, tmp_path, "trial-cell.toml", "signature")


def test_manifest_altered_after_signing_is_refused(tmp_path: Path) -> None:
    manifest = trial_manifest(tmp_path)
    sign(manifest, TEST_SIGNER)
    manifest.write_text(manifest.read_text().replace("speed_scale = 0.5", "speed_scale = 1.0"))
    _refused(run_trial(manifest, tmp_path), tmp_path, "trial-cell.toml")


def test_signed_by_an_untrusted_key_is_refused(tmp_path: Path) -> None:
    from kernel.signing import generate_keypair

    manifest = trial_manifest(tmp_path)
    generate_keypair(tmp_path / "other.key", tmp_path / "other.pub")
    sign(manifest, tmp_path / "other.key")
    _refused(run_trial(manifest, tmp_path), tmp_path, "trial-cell.toml")


def test_signed_manifest_without_an_envelope_is_refused(tmp_path: Path) -> None:
    manifest = trial_manifest(tmp_path, trial="")
    sign(manifest, TEST_SIGNER)
    _refused(run_trial(manifest, tmp_path), tmp_path, "trial", "envelope")


def test_a_model_the_signature_does_not_cover_is_refused(tmp_path: Path) -> None:
    manifest = trial_manifest(tmp_path)
    named = f'model_sha256 = "{digest(BUILTIN["ur5e"].path)}"\n'
    assert named in manifest.read_text()
    manifest.write_text(manifest.read_text().replace(named, "", 1))
    sign(manifest, TEST_SIGNER)
    message = _refused(run_trial(manifest, tmp_path), tmp_path, "robot.model_sha256: missing")
    assert named.strip() in message  # what to add, ready to copy


def test_a_model_file_changed_after_signing_is_refused(tmp_path: Path) -> None:
    model = tmp_path / "arm.xml"
    model.write_bytes(BUILTIN["ur5e"].path.read_bytes())
    manifest = trial_manifest(tmp_path)
    text = manifest.read_text().replace('kinematics = "ur5e"', f'model = "{model}"\n'
                                        f'tcp_frame = "{BUILTIN["ur5e"].tcp_frame}"', 1)
    manifest.write_text(text)
    sign(manifest, TEST_SIGNER)
    model.write_bytes(model.read_bytes() + b"<!-- edited -->\n")
    _refused(run_trial(manifest, tmp_path), tmp_path, "robot.model_sha256", "changed")


@pytest.mark.parametrize(("key", "line"), [
    ("trial.speed_scale", "speed_scale = 0.5"),
    ("trial.max_wrist_force_n", "max_wrist_force_n = 150.0"),
    ("trial.workspace_upper", "workspace_upper = [-0.20, 0.35, 0.50]"),
])
def test_an_envelope_missing_a_bound_is_refused(tmp_path: Path, key: str, line: str) -> None:
    manifest = trial_manifest(tmp_path, trial=TRIAL.replace(line + "\n", ""))
    sign(manifest, TEST_SIGNER)
    _refused(run_trial(manifest, tmp_path), tmp_path, key.split(".")[1])


def test_a_simulated_operator_is_refused(tmp_path: Path) -> None:
    manifest = trial_manifest(tmp_path, operator=False)
    sign(manifest, TEST_SIGNER)
    _refused(run_trial(manifest, tmp_path), tmp_path, "cell.simulated_operator")


# -- against a running safety monitor: the UR cell on an emulator the test starts -------------

def _ur_trial(tmp: Path, emulator: EmulatedController | SimpleNamespace, trial: str = TRIAL,
              name: str = "trial-cell.toml", watchdog: int = 25) -> Path:
    """The emulated UR cell as a trial (its monitor's sockets in ``tmp``, the controller's
    RTDE watchdog on), signed."""
    manifest = ur_manifest(tmp, emulator.host, name=name,
                           device_timeout_ms=UR_DEVICE_TIMEOUT_MS)
    text = manifest.read_text().replace("watchdog_periods = 0", f"watchdog_periods = {watchdog}")
    manifest.write_text(with_model_digest(text) + trial)
    sign(manifest, TEST_SIGNER)
    return manifest


class _Trial:
    """``warden trial`` as a child process with no terminal: it waits for the socket."""

    def __init__(self, manifest: Path, tmp: Path) -> None:
        self.socket = tmp / "operator.sock"
        self.process = subprocess.Popen(
            [sys.executable, "-m", "kernel.cli", "trial", str(manifest), "--keys",
             str(TEST_KEYS), "--journal-dir", str(tmp / "runs"), "--json", "-",
             "--log-format", "json", "--confirm-timeout", "60"],
            cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True)

    def confirm(self) -> dict[str, Any]:
        answers: list[dict[str, Any]] = []

        def answered() -> bool:  # the socket file may be there a moment before it listens
            if self.process.poll() is not None:
                return True
            try:
                answers.append(send(str(self.socket), "status", 5.0))
            except (FileNotFoundError, ConnectionRefusedError):
                return False
            return True

        wait_for(answered, "the trial's operator socket")
        if self.process.poll() is not None:
            raise AssertionError(f"the trial exited {self.process.returncode}: "
                                 f"{self.process.stderr.read() if self.process.stderr else ''}")
        before = answers[-1]
        assert before == {"ok": True, "run": "sim-ur5e-rtde",
                          "mode": "awaiting confirmation"}, before
        return send(str(self.socket), "confirm", 5.0)

    def finish(self, timeout_s: float = 120) -> tuple[int, dict[str, Any], str]:
        out, err = self.process.communicate(timeout=timeout_s)
        return self.process.returncode, json.loads(out) if out.strip() else {}, err

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.communicate()


@contextlib.contextmanager
def watched_trial(manifest: Path, tmp: Path) -> Iterator[tuple[Monitor, _Trial]]:
    """The monitor watching ``manifest``, then ``warden trial`` on it waiting for its
    confirmation; both ended on the way out."""
    monitor = Monitor(manifest, tmp)
    trial: _Trial | None = None
    try:
        monitor.wait_watching()
        trial = _Trial(manifest, tmp)
        yield monitor, trial
    finally:
        if trial is not None:
            trial.kill()
        monitor.stop()


@pytest.fixture
def emulator() -> Iterator[EmulatedController]:
    with EmulatedController(plant="mujoco") as controller:
        yield controller


@pytest.fixture
def idle_emulator() -> Iterator[EmulatedController]:
    """The UR controller without MuJoCo (a fraction of the CPU, and no model to load), for a
    trial refused before it moves anything: only its address and its RTDE link matter."""
    with EmulatedController(plant="kinematic") as controller:
        yield controller


def test_the_device_watchdog_switched_off_is_refused(tmp_path: Path) -> None:
    manifest = ur_manifest(tmp_path, "127.0.0.1")  # the safety tests' UR cell: watchdog off
    manifest.write_text(manifest.read_text() + TRIAL)
    sign(manifest, TEST_SIGNER)
    _refused(run_trial(manifest, tmp_path), tmp_path, "driver", "device-side watchdog")


@pytest.mark.slow
def test_no_safety_monitor_is_refused(tmp_path: Path,
                                      idle_emulator: EmulatedController) -> None:
    done = run_trial(_ur_trial(tmp_path, idle_emulator), tmp_path)
    _refused(done, tmp_path, "safety.status_socket", "no safety monitor answers")


def test_a_monitor_that_cannot_stop_the_arm_is_refused(tmp_path: Path) -> None:
    """One Dynamixel serial bus, one master: the monitor can only watch the heartbeat and
    report, the servos' Bus Watchdog is the only stop outside warden, and a trial needs more."""
    text = (MANIFESTS / "sim-dynamixel.toml").read_text()
    text = text.replace("cycles = 3", "cycles = 1\nsimulated_operator = false", 1)
    text += f'\n[operator]\nsocket = "{tmp_path / "operator.sock"}"\ngroup = "root"\n'
    manifest = tmp_path / "dynamixel-trial.toml"
    manifest.write_text(with_model_digest(text) + TRIAL + safety_table(tmp_path))
    sign(manifest, TEST_SIGNER)
    monitor = Monitor(manifest, tmp_path)
    try:
        assert not monitor.wait_watching()["can_stop"]
        done = run_trial(manifest, tmp_path)
    finally:
        monitor.stop()
    _refused(done, tmp_path, "the safety monitor cannot stop this arm", "Bus Watchdog")


@pytest.mark.slow
def test_a_monitor_that_has_lost_the_device_is_refused(
        tmp_path: Path, idle_emulator: EmulatedController) -> None:
    """Alive and answering is not enough: a monitor that no longer sees the arm says so, and
    the trial does not start."""
    manifest = _ur_trial(tmp_path, idle_emulator)
    monitor = Monitor(manifest, tmp_path)
    try:
        assert monitor.wait_watching()["connected"]
        idle_emulator.inject("data_stall")
        wait_for(lambda: not monitor.status()["ok"], "the monitor to report the lost device")
        done = run_trial(manifest, tmp_path)
    finally:
        monitor.stop()
    _refused(done, tmp_path, "the safety monitor is not ok")


@pytest.mark.slow
def test_a_monitor_watching_another_manifest_is_refused(
        tmp_path: Path, idle_emulator: EmulatedController) -> None:
    watched = _ur_trial(tmp_path, idle_emulator, name="watched.toml")
    trial = _ur_trial(tmp_path, idle_emulator, trial=TRIAL.replace("max_duration_s = 60.0",
                                                              "max_duration_s = 61.0"))
    monitor = Monitor(watched, tmp_path)
    try:
        monitor.wait_watching()
        done = run_trial(trial, tmp_path)
    finally:
        monitor.stop()
    _refused(done, tmp_path, "watched.toml", "not this manifest")


def _git_head() -> str:
    return subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                          text=True, check=True).stdout.strip()


@pytest.mark.slow
def test_a_confirmed_trial_runs_inside_its_envelope(
        tmp_path: Path, emulator: EmulatedController) -> None:
    manifest = _ur_trial(tmp_path, emulator)
    revisions = {_git_head()}
    with watched_trial(manifest, tmp_path) as (monitor, trial):
        answer = trial.confirm()
        assert answer["ok"] and answer["uid"] == os.getuid(), answer
        with operator_at_hand(tmp_path / "operator.sock",
                              emulator_at_rest(control_of(emulator))) as recovered:
            code, summary, err = trial.finish()
        assert monitor.status()["stops"] == 0
    print(f"recovered from: {recovered or 'no fallback'}")
    assert code == 0, err[-3000:]
    assert summary["cycles"]["verified"] == 1
    assert summary["trial"]["signer"] == TEST_KEY_ID
    assert summary["trial"]["confirmed_by_uid"] == os.getuid()
    assert summary["safety"]["sent"] > 0 and summary["safety"]["failed"] == 0
    head = json.loads(next((tmp_path / "runs").glob("*/journal.jsonl")).open().readline())
    assert head["provenance"]["manifest"]["sha256"] == hashlib.sha256(
        manifest.read_bytes()).hexdigest()
    assert head["provenance"]["signer"] == TEST_KEY_ID
    revisions.add(_git_head())  # others may commit to this checkout while the trial runs
    assert head["provenance"]["software"]["revision"] in revisions
    assert head["provenance"]["host"] == socket.gethostname()
    assert head["envelope"]["max_wrist_force_n"] == FORCE_LIMIT_N
    replayed = subprocess.run(
        [sys.executable, "-m", "kernel.cli", "replay",
         str(next((tmp_path / "runs").glob("*/journal.jsonl")))],
        cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)
    assert replayed.returncode == 0, replayed.stderr[-2000:]  # the envelope replays too
    card = err[:err.index("waiting")]
    for row in ("wrist force", "tool workspace", "stop: operator", "stop: safety monitor",
                "journal"):
        assert row in card, card


@pytest.mark.slow
def test_the_envelope_reached_ends_the_trial(tmp_path: Path,
                                             emulator: EmulatedController) -> None:
    """A box whose floor lies above the part: the descent to grasp it leaves the box."""
    manifest = _ur_trial(tmp_path, emulator, trial=TRIAL.replace(
        "workspace_lower = [-0.80, -0.40, 0.00]", "workspace_lower = [-0.80, -0.40, 0.20]"))
    with watched_trial(manifest, tmp_path) as (_, trial):
        trial.confirm()
        code, summary, err = trial.finish()
    assert code == 1, err[-3000:]
    assert "ENVELOPE" in summary["trial"]["ended"], summary["trial"]
    decisions = next((tmp_path / "runs").glob("*/decisions.jsonl")).read_text()
    assert '"ENVELOPE"' in decisions
    journal = next((tmp_path / "runs").glob("*/journal.jsonl"))
    replayed = subprocess.run([sys.executable, "-m", "kernel.cli", "replay", str(journal)],
                              cwd=ROOT, capture_output=True, text=True, timeout=300,
                              check=False)
    assert replayed.returncode == 0, replayed.stderr[-2000:]
    assert '"ENVELOPE"' in replayed.stdout  # the replayed core reaches the same bound
