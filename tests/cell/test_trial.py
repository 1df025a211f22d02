"""`warden trial`: what it refuses before anything starts, and a confirmed trial inside its
envelope.

Every refusal is a real `warden trial` process on a manifest signed (or not) with the
repository's test-only key; each must exit 2 with a message that names what is wrong, and must
not have started a device, a policy server or a journal.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from kernel.signing import sign
from tests.cell.harness import MANIFESTS

ROOT = MANIFESTS.parent
TEST_KEYS = MANIFESTS / "keys" / "test-only"
TEST_SIGNER = TEST_KEYS / "test-signer.key"
TRIAL = """
[trial]
max_cycles = 1
max_duration_s = 60.0
workspace_lower = [-0.80, -0.40, 0.00]
workspace_upper = [-0.20, 0.35, 0.50]
speed_scale = 0.5
max_wrist_force_n = 60.0
"""


def trial_manifest(tmp: Path, *, trial: str = TRIAL, operator: bool = True,
                   extra: str = "") -> Path:
    """The simulated UR5e cell as a trial: one cycle, a human recovers, its envelope."""
    text = (MANIFESTS / "sim-ur5e.toml").read_text()
    if operator:
        text = text.replace("cycles = 3", "cycles = 1\nsimulated_operator = false", 1)
    text += f'\n[operator]\nsocket = "{tmp / "operator.sock"}"\ngroup = "root"\n'
    text += trial + extra
    path = tmp / "trial-cell.toml"
    path.write_text(text)
    return path


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
    assert not (tmp / "runs").exists(), "a refused trial wrote a journal"
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


@pytest.mark.parametrize(("key", "line"), [
    ("trial.speed_scale", "speed_scale = 0.5"),
    ("trial.max_wrist_force_n", "max_wrist_force_n = 60.0"),
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
