"""``warden run`` with bad input: exit 2, a message naming the file and the key, nothing runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from kernel.cli import main
from tests.cell.harness import MANIFESTS

BASE = (MANIFESTS / "sim-ur5e.toml").read_text()


def _run(tmp_path: Path, text: str, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    path = tmp_path / "cell.toml"
    path.write_text(text)
    code = main(["run", str(path), "--no-journal"])
    return code, capsys.readouterr().err


@pytest.mark.parametrize(("change", "needle"), [
    (("cycles = 3", "cyclez = 3"), "cell.cyclez: unknown key"),
    (("[policy]", "[polcy]"), "polcy: unknown key"),
    (("acceleration_limits = [20.0, 20.0", "acceleration_limits = [20.0, -1.0"),
     "robot.acceleration_limits"),
    (("position_limits = [[-6.2832, 6.2832]", "position_limits = [[6.2832, -6.2832]"),
     "robot.position_limits[0]"),
    (('name = "sim"', 'name = "sim"\nport = "/dev/ttyUSB0"'), "driver.port: unknown key"),
    (('name = "sim"', 'name = "warp-drive"'), "driver.name"),
    (("max_divergence = 0.03", "max_divergence = \"small\""), "phases.PRE_CONTACT.max_divergence"),
    (("control_period_ms = 2", "control_period_ms = 1e-9"), "timing.control_period_ms"),
    (("clock_uncertainty_ms = ", "clock_uncertainty_ms = 1e303 #"),
     "timing.clock_uncertainty_ms"),
    (("[policy]", '[emulator]\nplant = "clay"\n\n[policy]'), "emulator.plant: unknown value"),
    (("[policy]", "[emulator]\nlaunch = 0\n\n[policy]"), "emulator.launch: expected bool"),
    (("[policy]", "[emulator]\nplnat = 1\n\n[policy]"), "emulator.plnat: unknown key"),
    (("max_underrun_ms = 500", "max_underrun_ms = 400"),
     "phases.PRE_CONTACT.max_underrun_ms: 400 ms must be longer than"),
    (("max_underrun_ms = 500", "#"), "phases.PRE_CONTACT.max_underrun_ms: 250 ms (max_action"),
    (("[policy]", "[policy]\nheartbeat_timeout_ms = 600"), "must be longer than policy.heart"),
    (("[policy]", "[policy]\nmax_chunks_per_s = 0"), "policy: max_chunks_per_s must be positive"),
    (("[policy]", "[policy]\nmax_frame_bytes = 2000000"), "policy: max_frame_bytes must be in"),
    (("[policy]", "[policy]\nheartbeat_timeout_ms = 50"),
     "heartbeat_timeout_ms (50.0) must be longer than heartbeat_interval_ms"),
])
def test_bad_manifest_exits_2_naming_the_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], change: tuple[str, str], needle: str
) -> None:
    assert change[0] in BASE
    code, err = _run(tmp_path, BASE.replace(change[0], change[1], 1), capsys)
    assert code == 2
    assert needle in err and str(tmp_path / "cell.toml") in err
    assert "Traceback" not in err


def test_missing_manifest_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", str(tmp_path / "nowhere.toml")]) == 2
    assert "cannot read file" in capsys.readouterr().err


def test_real_device_unreachable_exits_2(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    text = (MANIFESTS / "sim-ur5e-rtde.toml").read_text()
    text = text.replace('name = "ur_rtde"', 'name = "ur_rtde"\nhost = "127.0.0.9"\n'
                        'connect_timeout_s = 0.5\nreconnect_attempts = 0', 1)
    text = text.replace('plant = "mujoco"', "launch = false", 1)
    text = text.replace("cycle_timeout_s = 30.0", "cycle_timeout_s = 30.0\n"
                        "simulated_operator = false", 1)
    code, err = _run(tmp_path, text, capsys)
    assert code == 2
    assert "127.0.0.9" in err and "check" in err


@pytest.mark.parametrize(("manifest", "change", "needle"), [
    ("sim-canopen.toml", ("gripper_node = 7", "gripper_node = 3"),
     "driver: gripper_node 3 is also in node_ids"),
    ("sim-dynamixel.toml", ("gripper_id = 7", "gripper_id = 7\ngripper_current_ma = 9e3"),
     "driver: gripper_current_ma"),
    ("sim-ur5e-rtde.toml", ("gripper_feedback_open = 10.0", "gripper_feedback_open = 5.0"),
     "driver.gripper_feedback_open"),
])
def test_a_driver_setting_is_checked_before_its_emulator_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], manifest: str, change: tuple[str, str],
    needle: str,
) -> None:
    text = (MANIFESTS / manifest).read_text()
    assert change[0] in text
    code, err = _run(tmp_path, text.replace(change[0], change[1], 1), capsys)
    assert code == 2 and needle in err and "Traceback" not in err


def test_an_emulator_that_does_not_start_exits_2(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    text = (MANIFESTS / "sim-ur5e-rtde.toml").read_text()
    text = text.replace('plant = "mujoco"', 'plant = "mujoco"\nhost = "10.1.2.3"', 1)
    code, err = _run(tmp_path, text, capfd)
    assert code == 2
    assert "cannot start the device" in err and "stubs.ur_controller" in err
    assert "not a loopback address" in err  # the emulator's own message, above


def test_simulated_operator_is_refused_on_a_real_device(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = (MANIFESTS / "sim-ur5e-rtde.toml").read_text()
    text = text.replace('name = "ur_rtde"', 'name = "ur_rtde"\nhost = "127.0.0.9"', 1)
    text = text.replace('plant = "mujoco"', "launch = false", 1)
    code, err = _run(tmp_path, text, capsys)
    assert code == 2 and "cell.simulated_operator" in err


def test_json_on_stdout_is_machine_readable(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["run", "--clock", "virtual", "--cycles", "1", "--no-journal", "--json", "-"])
    captured = capsys.readouterr()
    summary = json.loads(captured.out)  # the summary table went to stderr
    assert code == 0 and summary["cycles"]["verified"] == 1
    assert "verified" in captured.err
