"""The manifest loader's safety rules, one fast test each, on the loader alone (before, four of
these were caught only by whole-cell runs; issue 15, item 14). Each manifest is a shipped one
with one line changed, loaded from its bytes: nothing is started.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from kernel.app.trial import load_trial
from kernel.manifest import Manifest, ManifestError, load_manifest
from kernel.scenario.fields import ScenarioError
from kernel.signing import generate_keypair, sign

ROOT = Path(__file__).resolve().parents[2]
SIM = ROOT / "manifests" / "sim-ur5e.toml"
RTDE = ROOT / "manifests" / "sim-ur5e-rtde.toml"
TRIAL = """
[trial]
max_cycles = 1
max_duration_s = 60.0
workspace_lower = [-0.80, -0.40, 0.00]
workspace_upper = [-0.20, 0.35, 0.50]
speed_scale = {speed}
max_wrist_force_n = 150.0
"""


def load(source: Path, old: str = "", new: str = "", extra: str = "") -> Manifest:
    text = source.read_text()
    if old:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return load_manifest(source, content=(text + extra).encode())


def refused(source: Path, old: str = "", new: str = "", extra: str = "") -> str:
    with pytest.raises((ManifestError, ScenarioError)) as caught:
        load(source, old, new, extra)
    message = str(caught.value)
    assert str(source) in message, message
    return message


def test_the_shipped_manifests_load() -> None:
    assert load(SIM).driver_name == "sim" and load(RTDE).driver_name == "ur_rtde"


def test_a_real_device_without_a_state_watchdog_is_refused() -> None:
    message = refused(RTDE, "state_timeout_ms = 50", "")
    assert "state_timeout_ms" in message


def test_a_lower_position_limit_above_its_upper_is_refused() -> None:
    message = refused(SIM, "position_limits = [[-6.2832, 6.2832]",
                      "position_limits = [[1.0, -1.0]")
    assert "position_limits" in message and "exceeds" in message


def test_an_unknown_top_level_key_is_refused() -> None:
    # before the first table: a key after a table header would belong to that table
    message = refused(SIM, 'name = "sim-ur5e"', 'name = "sim-ur5e"\nspeed_limit_override = 10')
    assert "speed_limit_override" in message and "unknown key" in message


def test_an_unknown_allowlist_key_is_refused() -> None:
    message = refused(SIM, extra='\n[[allowlist]]\npolicy_checkpoint = "x"\nconfig_hash = "y"\n'
                                 'skill_version = "any"\n')
    assert "allowlist" in message and "skill_version" in message


@pytest.mark.parametrize(("underrun_ms", "accepted"), [(450, False), (451, True)])
def test_a_dead_link_must_be_declared_before_the_queue_underruns(
    underrun_ms: int, accepted: bool
) -> None:
    # the link's loss bound: heartbeat_timeout_ms 350 + heartbeat_interval_ms 100 (defaults)
    change = ("max_underrun_ms = 500", f"max_underrun_ms = {underrun_ms}")
    if accepted:
        assert load(SIM, *change).name == "sim-ur5e"
    else:
        message = refused(SIM, *change)
        assert "max_underrun_ms" in message and "DEGRADED" in message


@pytest.mark.parametrize("speed", [1.0, 0.01])
def test_a_trial_speed_scale_inside_its_bounds_is_accepted(speed: float) -> None:
    trial = load(SIM, extra=TRIAL.format(speed=speed)).trial
    assert trial is not None and trial.speed_scale == speed


@pytest.mark.parametrize("speed", [1.01, 2.0, 10.0, 0.009, 0.0])
def test_a_trial_speed_scale_beyond_its_bounds_is_refused(speed: float) -> None:
    message = refused(SIM, extra=TRIAL.format(speed=speed))
    assert "speed_scale" in message


def test_a_trial_without_a_state_watchdog_is_refused(tmp_path: Path) -> None:
    # the simulated driver needs no watchdog in a run; a trial needs one whatever the driver
    text = SIM.read_text().replace("state_timeout_ms = 50", "") + TRIAL.format(speed=0.5)
    manifest = tmp_path / "trial.toml"
    manifest.write_text(text)
    keys = tmp_path / "keys"
    keys.mkdir()
    generate_keypair(tmp_path / "signer.key", keys / "signer.pub")
    sign(manifest, tmp_path / "signer.key")
    assert load_manifest(manifest).core.state_timeout_ns is None  # a run would accept it
    with pytest.raises(ManifestError, match=r"state_timeout_ms.*state watchdog"):
        load_trial(manifest, keys)


def test_the_gripper_event_threshold_defaults_to_one_millimetre() -> None:
    # what decides whether a trim would delete a gripper closing (tests/core/test_gates.py)
    assert load(SIM).core.limits.gripper_event_threshold == 1e-3
