"""``warden run`` with bad input: exit 2, a message naming the file and the key, nothing runs."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

import pytest

from kernel.cli import main
from kernel.cli_run import checked_manifest
from tests.cell.harness import MANIFESTS
from tests.filesystems import read_only_tmpfs

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
    (("[policy]", "[policy]\nmax_chunks_per_s = 0"),
     "policy.max_chunks_per_s: must be at least 0.1, got 0"),
    (("[policy]", "[policy]\nmax_frame_bytes = 2000000"),
     "policy.max_frame_bytes: must be at most 1048576, got 2000000"),
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
    operator = f'\n[operator]\nsocket = "{tmp_path / "operator.sock"}"\ngroup = "root"\n'
    code, err = _run(tmp_path, text + operator, capsys)
    assert code == 2
    assert "127.0.0.9" in err and "check" in err


def test_a_real_device_without_its_operator_socket_exits_2_before_touching_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = (MANIFESTS / "sim-ur5e-rtde.toml").read_text()
    text = text.replace('name = "ur_rtde"', 'name = "ur_rtde"\nhost = "127.0.0.9"', 1)
    text = text.replace('plant = "mujoco"', "launch = false", 1)
    text = text.replace("cycle_timeout_s = 30.0", "cycle_timeout_s = 30.0\n"
                        "simulated_operator = false", 1)
    operator = f'\n[operator]\nsocket = "{tmp_path / "absent" / "operator.sock"}"\n'
    code, err = _run(tmp_path, text + operator, capsys)
    assert code == 2
    assert "operator.socket" in err and "127.0.0.9" not in err  # the device was never tried


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
    code = main(["run", "--clock", "virtual", "--cycles", "1", "--no-journal", "--json", "-",
                 "--log-format", "console"])
    captured = capsys.readouterr()
    summary = json.loads(captured.out)  # the summary table went to stderr
    assert code == 0 and summary["cycles"]["verified"] == 1
    assert "warden run: 1/1 cycles verified" in captured.err
    assert "cycle 1/1  start" in captured.err  # progress, one plain line per phase change


def test_with_json_logs_every_stderr_line_is_json(capsys: pytest.CaptureFixture[str]) -> None:
    """Progress and the cycle's result are log lines; the summary is stdout's JSON, no table."""
    code = main(["run", "--clock", "virtual", "--cycles", "1", "--no-journal", "--json", "-",
                 "--log-format", "json"])
    captured = capsys.readouterr()
    assert code == 0 and json.loads(captured.out)["cycles"]["verified"] == 1
    lines = [json.loads(line) for line in captured.err.splitlines()]
    progress = [line for line in lines if line["event"] == "progress"]
    assert progress[0]["step"] == "start" and progress[-1]["step"] == "done"
    [cycle] = [line for line in lines if line["event"] == "cycle done"]
    assert (cycle["cycle"], cycle["of"], cycle["verified"]) == (1, 1, True)


# -- bad input found by new users: every case exits 2 before anything starts ----------------------


@pytest.fixture
def nothing_starts(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test if ``warden run`` gets as far as building a world (a plant, an emulator, a
    device): every check below must happen while loading."""
    def started(*_: object) -> None:
        raise AssertionError("a device or emulator was started before the input was refused")

    monkeypatch.setattr("kernel.app.session.world_for", started)


BAD_VALUES = [
    # [cell]
    (("cycle_timeout_s = 30.0", "cycle_timeout_s = inf"), "cell.cycle_timeout_s: must be a finite"),
    (("cycle_timeout_s = 30.0", "cycle_timeout_s = nan"), "cell.cycle_timeout_s: must be a finite"),
    (("cycle_timeout_s = 30.0", "cycle_timeout_s = 1e9"), "cell.cycle_timeout_s: must be at most"),
    (("cycles = 3", "cycles = 0"), "cell.cycles: must be at least 1"),
    (("cycles = 3", "cycles = 10000000000"), "cell.cycles: must be at most"),
    (("seed = 7", "seed = -1"), "cell.seed: must be at least 0"),
    (("insertion_tolerance_m = 0.015", "insertion_tolerance_m = -0.1"),
     "cell.insertion_tolerance_m"),
    # [policy]
    (("chunk_horizon = 20", "chunk_horizon = 0"), "policy.chunk_horizon: must be at least 1"),
    (("chunk_horizon = 20", "chunk_horizon = 1000000"), "policy.chunk_horizon: must be at most"),
    (("action_dt_ms = 20.0", "action_dt_ms = 0"), "policy.action_dt_ms: must be at least"),
    (("latency_median_ms = 25.0", "latency_median_ms = -5.0"),
     "policy.latency_median_ms: must be at least 0"),
    (("latency_p95_ms = 60.0", "latency_p95_ms = 10.0"),
     "policy.latency_p95_ms: must be at least latency_median_ms"),
    (("port = 0 ", "port = -1 "), "policy.port: must be at least 0"),
    (("port = 0 ", "port = 70000 "), "policy.port: must be at most 65535"),
    (("launch = true ", "launch = false "), "policy.port: must be the server's port"),
    (("clock_offset_ms = 137.0", "clock_offset_ms = 1e300"),
     "policy.clock_offset_ms: must be at most"),
    (("noise_rad = 0.0001", "noise_rad = nan"), "policy.noise_rad: must be a finite"),
    # a launched reference server listens on loopback unless the manifest means otherwise
    (('host = "127.0.0.1"', 'host = "0.0.0.0"'), "policy.host: '0.0.0.0' is not a loopback"),
    (('host = "127.0.0.1"', 'host = "192.0.2.2"'), "policy.host: '192.0.2.2' is not a "
                                                   "loopback"),
    (('host = "127.0.0.1"', 'host = "robot-pc.local"'), "policy.host: 'robot-pc.local'"),
    (('host = "127.0.0.1"', 'host = "0.0.0.0"\nexpose = 1'), "policy.expose: expected bool"),
    # the run's name names a directory
    (('name = "sim-ur5e"', 'name = "../../x"'), "name: '../../x' is not a safe run name"),
    (('name = "sim-ur5e"', 'name = ".hidden"'), "name: '.hidden' is not a safe run name"),
    (('name = "sim-ur5e"', 'name = "a/b"'), "name: 'a/b' is not a safe run name"),
    (('name = "sim-ur5e"', "name = 5"), "name: 5 is not a safe run name"),
    # [robot], [timing], [phases], [session]: the sections a scenario has
    (("velocity_limits = [3.1416,", "velocity_limits = [1e9,"), "robot.velocity_limits[0]"),
    (("acceleration_limits = [20.0,", "acceleration_limits = [1e12,"),
     "robot.acceleration_limits[0]"),
    (("position_limits = [[-6.2832, 6.2832]", "position_limits = [[-1e12, 1e12]"),
     "robot.position_limits[0][0]"),
    (("max_divergence = 0.03", "max_divergence = 1e9"), "phases.PRE_CONTACT.max_divergence"),
    (("state = [0.0, -1.5708", "state = [100.0, -1.5708"), "session.state[0]: 100 is outside"),
    (("dof = 6", "dof = 300000000"), "robot.dof: must be at most 64"),
    (("control_period_ms = 2", "control_period_ms = 0"), "timing.control_period_ms"),
    (("state_timeout_ms = 50", "state_timeout_ms = 1"), "timing.state_timeout_ms: must be at "
                                                        "least one control period"),
    # [task]: checked before anything starts too
    (("home_q = [0.0,", "home_q = [100.0,"), "task.home_q[0]: 100 is outside"),
    (("hole_depth = 0.03", "hole_depth = inf"), "task.hole_depth: must be a finite number"),
    (("hole_depth = 0.03", "hole_depth = 1e9"), "task.hole_depth: must be at most"),
    (("hole_top = [-0.55,", "hole_top = [-1e6,"), "task.hole_top[0]"),
    (("gripper_open = 0.085", "gripper_open = 0.0"), "task.gripper_open: must exceed"),
    (("tool_rotation = [[0.0, 1.0, 0.0]", "tool_rotation = [[0.0, 1e300, 0.0]"),
     "task.tool_rotation[0][1]: must be at most 1"),
    (("tool_rotation = [[0.0, 1.0, 0.0]", "tool_rotation = [[0.0, 0.9, 0.0]"),
     "task.tool_rotation: not a rotation matrix"),
    # fail closed
    (("max_divergence = 0.03", "max_divergance = 0.03"),
     "phases.PRE_CONTACT.max_divergance: unknown key"),
    (("[timing]", "[timing]\nperiod_ms = 2"), "timing.period_ms: unknown key"),
    (("[session]", "[session]\nepoch = 2"), "session.epoch: unknown key"),
    (("[robot]", "[robot]\nmax_speed = 1.0"), "robot.max_speed: unknown key"),
    (("[phases.RETREAT]", "[motion]\nplanner_speed = 1.0\n\n[phases.RETREAT]"),
     "motion.planner_speed: unknown key"),
    (("velocity_limits = [3.1416, 3.1416, 3.1416, 3.1416, 3.1416, 3.1416]", ""),
     "robot: missing required key 'velocity_limits'"),
    (("acceleration_limits = [20.0, 20.0, 20.0, 20.0, 20.0, 20.0]", ""),
     "robot: missing required key 'acceleration_limits'"),
    (("position_limits = [[-6.2832, 6.2832]", "unused = [[-6.2832, 6.2832]"),
     "robot.unused: unknown key"),
]


@pytest.mark.parametrize(("change", "needle"), BAD_VALUES,
                         ids=[f"{c[1].strip()[:40]}" for c, _ in BAD_VALUES])
@pytest.mark.usefixtures("nothing_starts")
def test_an_absurd_value_exits_2_before_anything_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], change: tuple[str, str], needle: str
) -> None:
    assert change[0] in BASE
    code, err = _run(tmp_path, BASE.replace(change[0], change[1], 1), capsys)
    assert code == 2, err
    assert needle in err and str(tmp_path / "cell.toml") in err
    assert "Traceback" not in err and err.count("\n") == 1


@pytest.mark.usefixtures("nothing_starts")
def test_a_missing_position_limit_exits_2(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    start = BASE.index("position_limits = ")
    end = BASE.index("velocity_limits = ")
    code, err = _run(tmp_path, BASE[:start] + BASE[end:], capsys)
    assert code == 2 and "robot: missing required key 'position_limits'" in err


@pytest.mark.usefixtures("nothing_starts")
def test_a_name_outside_the_journal_directory_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "journal").mkdir()
    path = tmp_path / "cell.toml"
    path.write_text(BASE.replace('name = "sim-ur5e"', 'name = "../escaped"', 1))
    code = main(["run", str(path), "--clock", "virtual", "--cycles", "1",
                 "--journal-dir", str(tmp_path / "journal")])
    assert code == 2 and "name" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cell.toml", "journal"]
    assert not any((tmp_path / "journal").iterdir())


@pytest.mark.parametrize("stem", ["my cell", ".hidden", "café"])
@pytest.mark.usefixtures("nothing_starts")
def test_a_file_name_that_is_no_safe_run_name_needs_a_name(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], stem: str
) -> None:
    path = tmp_path / f"{stem}.toml"
    path.write_text(BASE.replace('name = "sim-ur5e"\n', "", 1))
    assert main(["run", str(path), "--no-journal"]) == 2
    assert "name: missing, and the file name" in capsys.readouterr().err


@pytest.mark.parametrize(("raw", "needle"), [
    (BASE.encode().replace(b"peg_insert", b"peg\xe9insert", 1), "not UTF-8 text (byte 0xe9)"),
    (BASE.encode().replace(b"seed = 7", b"seed = " + b"9" * 5000, 1),
     "line 10: cell.seed: an integer of thousands of digits"),
    (BASE.encode().replace(b"seed = 7", b"seed = " + b"9" * 400, 1),
     "cell.seed: an integer of 400 digits"),
    (BASE.encode().replace(b"seed = 7", b"seed = " + b"[" * 50_000 + b"]" * 50_000, 1),
     "nested too deeply"),
    (BASE.encode().replace(b"dof = 6", b"dof = " + b"[" * 40 + b"6" + b"]" * 40, 1),
     "robot.dof[0]"),
    (BASE.encode().replace(b'skill = "peg_insert"', b'skill = "\\ud800"', 1), "not valid TOML"),
], ids=["not UTF-8", "5000 digits", "400 digits", "nested", "nested 40", "surrogate"])
@pytest.mark.usefixtures("nothing_starts")
def test_a_manifest_no_parser_survives_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], raw: bytes, needle: str
) -> None:
    path = tmp_path / "cell.toml"
    path.write_bytes(raw)
    assert main(["run", str(path), "--no-journal"]) == 2
    err = capsys.readouterr().err
    assert needle in err and str(path) in err and "Traceback" not in err


@pytest.mark.parametrize("manifest", ["sim-ur5e-rtde.toml", "sim-dynamixel.toml",
                                      "sim-canopen.toml"])
@pytest.mark.usefixtures("nothing_starts")
def test_a_real_device_needs_the_state_watchdog(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], manifest: str
) -> None:
    text = (MANIFESTS / manifest).read_text()
    lines = [line for line in text.splitlines() if not line.startswith("state_timeout_ms")]
    code, err = _run(tmp_path, "\n".join(lines), capsys)
    assert code == 2 and "timing: missing required key 'state_timeout_ms'" in err


@pytest.mark.parametrize("cycles", ["0", "-3", "10000000000"])
@pytest.mark.usefixtures("nothing_starts")
def test_cycles_on_the_command_line_are_bounded(
    capsys: pytest.CaptureFixture[str], cycles: str
) -> None:
    assert main(["run", "--cycles", cycles, "--no-journal"]) == 2
    assert "--cycles: must be 1 to 1000000" in capsys.readouterr().err


@pytest.mark.usefixtures("nothing_starts")
def test_a_virtual_clock_with_a_device_exits_2_before_it_starts(
    capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["run", str(MANIFESTS / "sim-ur5e-rtde.toml"), "--clock", "virtual",
                 "--no-journal"]) == 2
    assert "cell.clock: a virtual clock needs the in-process plant" in capsys.readouterr().err


def test_every_shipped_manifest_is_within_the_bounds() -> None:
    for path in sorted(MANIFESTS.glob("*.toml")):
        checked_manifest(path)


@pytest.mark.parametrize("place", ["/dev/null", "/proc", "/proc/self/fd", "read-only"])
@pytest.mark.parametrize("given_by", ["option", "manifest"])
@pytest.mark.usefixtures("nothing_starts")
def test_a_journal_directory_that_cannot_hold_journals_exits_2_naming_the_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], place: str, given_by: str
) -> None:
    with contextlib.ExitStack() as stack:
        directory = place if place != "read-only" else str(
            stack.enter_context(read_only_tmpfs(tmp_path / "ro")))
        path = tmp_path / "cell.toml"
        argv = ["run", str(path), "--clock", "virtual", "--cycles", "1"]
        if given_by == "option":
            path.write_text(BASE)
            argv += ["--journal-dir", directory]
            key = "--journal-dir"
        else:
            path.write_text(BASE.replace('directory = "runs"', f'directory = "{directory}"', 1))
            key = f"{path}: journal.directory"
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"{key}: {directory}: cannot keep run journals there" in err, err


@pytest.mark.parametrize(("host", "expose"), [("127.0.0.2", False), ("localhost", False),
                                              ("::1", False), ("0.0.0.0", True)])
def test_a_reference_server_host_on_loopback_or_exposed_on_purpose_is_accepted(
    tmp_path: Path, host: str, expose: bool
) -> None:
    path = tmp_path / "cell.toml"
    path.write_text(BASE.replace('host = "127.0.0.1"', f'host = "{host}"\nexpose = '
                                 f'{str(expose).lower()}', 1))
    assert checked_manifest(path).policy.host == host
    remote = BASE.replace('launch = true ', 'launch = false', 1).replace(
        'host = "127.0.0.1"', 'host = "192.0.2.7"', 1).replace("port = 0 ", "port = 8765", 1)
    path.write_text(remote)  # a server warden does not launch may be anywhere
    assert checked_manifest(path).policy.host == "192.0.2.7"

