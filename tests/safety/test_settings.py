"""The manifest's [safety] table: defaults, refusals that name the key, what warden reads."""

from __future__ import annotations

from pathlib import Path

import pytest

from kernel.manifest import ManifestError, load_manifest
from kernel.safety.settings import SafetySettings

MANIFESTS = Path(__file__).resolve().parents[2] / "manifests"


def _with_safety(tmp_path: Path, table: str, base: str = "sim-ur5e.toml") -> Path:
    path = tmp_path / "cell.toml"
    path.write_text((MANIFESTS / base).read_text() + "\n[safety]\n" + table)
    return path


def test_no_table_means_no_heartbeat_and_no_monitor() -> None:
    assert load_manifest(MANIFESTS / "sim-ur5e.toml").safety is None


def test_the_defaults_are_the_documented_ones(tmp_path: Path) -> None:
    settings = load_manifest(_with_safety(tmp_path, "max_wrist_force_n = 120\n")).safety
    assert settings == SafetySettings(max_wrist_force_n=120.0)
    assert str(settings.heartbeat_path) == "/run/warden-safety/heartbeat.sock"
    assert str(settings.status_path) == "/run/warden-safety/status.sock"
    assert (settings.heartbeat_periods, settings.heartbeat_timeout_ms) == (5, 200.0)
    assert (settings.check_period_ms, settings.device_timeout_ms) == (4.0, 250.0)
    assert settings.closing_timeout_ms == 10_000.0


@pytest.mark.parametrize(("table", "message"), [
    ("heartbeat_timeout = 100\n", "safety.heartbeat_timeout: unknown key"),
    ("heartbeat_periods = 0\n", "safety.heartbeat_periods: must be at least 1, got 0"),
    ("max_wrist_force_n = -5\n", "safety.max_wrist_force_n: must be positive, got -5.0"),
    ("max_wrist_force_n = 'lots'\n", "safety.max_wrist_force_n: expected float, got 'lots'"),
    ("check_period_ms = 50\nheartbeat_timeout_ms = 80\n",
     "heartbeat_timeout_ms = 80.0 must be at least two check periods"),
    ("heartbeat_socket = 'run/hb.sock'\n", "heartbeat_socket = 'run/hb.sock' must be an "
                                           "absolute path"),
    ("sim_port = 70000\n", "safety.sim_port: must be at most 65535, got 70000"),
])
def test_bad_values_are_refused_naming_the_key(tmp_path: Path, table: str, message: str) -> None:
    with pytest.raises(ManifestError, match=r"cell\.toml: safety") as refused:
        load_manifest(_with_safety(tmp_path, table))
    assert message in str(refused.value)


def test_a_timeout_shorter_than_two_heartbeats_is_refused(tmp_path: Path) -> None:
    # 2 ms ticks, one heartbeat every 30 ticks: 60 ms apart, so 100 ms could not survive one
    # late heartbeat.
    path = _with_safety(tmp_path, "heartbeat_periods = 30\nheartbeat_timeout_ms = 100\n")
    with pytest.raises(ManifestError) as refused:
        load_manifest(path)
    assert "safety.heartbeat_timeout_ms: heartbeat_timeout_ms = 100.0 is shorter than two " \
           "heartbeats (30 periods of 2 ms each = 60 ms apart)" in str(refused.value)
