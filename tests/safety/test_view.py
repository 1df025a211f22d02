"""The monitor's own view of a manifest: warden's numbers, warden's refusals, none of its core."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from kernel.manifest import ManifestError, load_manifest
from kernel.safety.view import ViewError, read_view

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = sorted((ROOT / "manifests").glob("*.toml"))
VELOCITY = "velocity_limits = [3.1416, 3.1416, 3.1416, 3.1416, 3.1416, 3.1416]"


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_the_view_reads_what_warden_reads(path: Path) -> None:
    manifest, view = load_manifest(path), read_view(path)
    core = manifest.core.limits
    for name in ("lower", "upper", "velocity", "acceleration"):
        assert np.array_equal(getattr(core, name), np.array(getattr(view.limits, name))), name
    assert (view.limits.gripper_index, view.limits.arm) == (
        core.gripper_index, tuple(np.flatnonzero(core.arm_mask).tolist()))
    assert (view.name, view.digest, view.safety) == (manifest.name, manifest.digest,
                                                     manifest.safety)
    assert (view.driver_name, view.driver_settings, view.emulator) == (
        manifest.driver_name, manifest.driver_settings, manifest.emulator)


def _cell(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "cell.toml"
    path.write_text(text)
    return path


def _replaced(old: str, new: str, base: str = "sim-ur5e.toml") -> str:
    text = (ROOT / "manifests" / base).read_text()
    assert old in text
    return text.replace(old, new, 1)


@pytest.mark.parametrize(("text", "message"), [
    (_replaced(VELOCITY, "velocity_limits = -1"),
     "robot.velocity_limits: must be positive"),
    (_replaced(VELOCITY, "velocity_limit = 3.1416"), "robot.velocity_limit: unknown key"),
    (_replaced(VELOCITY, ""), "robot: missing required key 'velocity_limits'"),
    (_replaced("dof = 6", "dof = 6\nmodle = 'ur5e.urdf'"), "robot.modle: unknown key"),
    (_replaced("dof = 6", "dof = 6.5"), "robot.dof"),
    (_replaced("control_period_ms = 2", "control_period_ms = 5000"),
     "timing.control_period_ms"),
    ((ROOT / "manifests/sim-ur5e.toml").read_text() + "\n[safety]\nheartbeat_periods = 30\n"
     "heartbeat_timeout_ms = 100\n", "safety.heartbeat_timeout_ms: heartbeat_timeout_ms = "
     "100.0 is shorter than two heartbeats"),
    ((ROOT / "manifests/sim-ur5e.toml").read_text() + "\n[safety]\nheartbeat_timeout = 1\n",
     "safety.heartbeat_timeout: unknown key"),
    (_replaced("[driver]", "[emulator]\nlanch = false\n[driver]"), "emulator.lanch: unknown key"),
    ("name = 'x'\n[robot\n", "cell.toml: not valid TOML"),
    (_replaced('name = "sim-ur5e"', "name = '../up'"), "name: '../up' is not a safe run name"),
])
def test_a_bad_table_the_monitor_reads_is_refused_as_warden_refuses_it(
        tmp_path: Path, text: str, message: str) -> None:
    path = _cell(tmp_path, text)
    with pytest.raises(ManifestError) as warden:
        load_manifest(path)
    with pytest.raises(ViewError) as monitor:
        read_view(path)
    assert str(monitor.value) == str(warden.value)
    assert str(monitor.value).startswith(f"{path}: ") and message in str(monitor.value)


def test_the_view_needs_neither_the_robot_model_nor_the_rest_of_the_configuration(
        tmp_path: Path) -> None:
    text = _replaced("latency_median_ms = 25.0", "latency_median_ms = -3",
                     "sim-ur5e-cartesian.toml").replace('kinematics = "ur5e"',
                                                        'kinematics = "no-such-model"')
    text = text.split("\n[geometry]")[0]  # the space check needs the model (its own test)
    path = _cell(tmp_path, text)
    with pytest.raises(ManifestError):
        load_manifest(path)  # warden needs both: it refuses
    assert read_view(path).limits.velocity  # the monitor reads neither


def test_reading_the_view_imports_nothing_of_wardens_core() -> None:
    probe = ("import sys\nfrom kernel.safety.view import read_view\n"
             "import kernel.safety.service, kernel.safety.canopen, kernel.safety.sim\n"
             f"read_view({str(SHIPPED[0])!r})\n"
             "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] in "
             "('assurance', 'skills', 'pinocchio', 'mujoco') or m.startswith('kernel.core') "
             "or m in ('kernel.manifest', 'kernel.settings', 'kernel.config.build'))))\n")
    loaded = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True,
                            text=True, check=True).stdout.split()
    assert loaded == ["assurance", "assurance.reasons"]  # the drivers' error codes only
