"""``warden run`` with absurd ``[policy]`` link limits and vendor driver settings: exit 2, one
line naming the file and the key, no traceback, and nothing started (no plant, emulator,
device or policy server; no run directory left behind).

``[policy]`` is refused while the manifest loads (``tests/cell/test_run_cli.py``'s
``nothing_starts``: the world is never built). ``[driver]`` is checked by the world itself,
before its emulator process starts: there, the emulator process is the tripwire.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from drivers.dynamixel._sdk import SDK_BAUD_RATES
from drivers.dynamixel.tables import BAUD_RATES
from kernel.cli import main
from stubs.dynamixel_bus.__main__ import BAUD_CODES
from tests.cell.harness import MANIFESTS
from tests.cell.test_run_cli import nothing_starts

__all__ = ["nothing_starts"]  # the fixture, shared with tests/cell/test_run_cli.py


@pytest.fixture
def no_emulator_starts(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test if an emulator process (and so the plant behind it) is started, or the
    policy server, or a device is connected."""
    def started(*_: object, **__: object) -> None:
        raise AssertionError("an emulator, a server or a device was started before the input "
                             "was refused")

    monkeypatch.setattr("stubs.cell.emulated.EmulatorProcess", started)
    monkeypatch.setattr("kernel.app.live.bring_up", started)
    monkeypatch.setattr("kernel.app.live._Launched", started)


def _run(tmp_path: Path, manifest: str, change: tuple[str, str],
         capsys: pytest.CaptureFixture[str]) -> tuple[int, str, Path]:
    text = (MANIFESTS / manifest).read_text()
    assert change[0] in text, change
    path = tmp_path / "cell.toml"
    path.write_text(text.replace(change[0], change[1], 1))
    runs = tmp_path / "runs"
    code = main(["run", str(path), "--journal-dir", str(runs)])
    return code, capsys.readouterr().err, runs


def _assert_refused(code: int, err: str, runs: Path, path: Path, needle: str) -> None:
    assert code == 2, err
    assert "Traceback" not in err and err.count("\n") == 1, err
    assert str(path) in err and needle in err, err
    assert not runs.exists() or not any(runs.iterdir()), list(runs.iterdir())


POLICY = [
    ("max_chunks_per_s = inf", "policy.max_chunks_per_s: must be a finite number of at most 10000"),
    ("max_chunks_per_s = nan", "policy.max_chunks_per_s: must be a finite number of at most 10000, "
                               "got nan"),
    ("max_chunks_per_s = 20000.0", "policy.max_chunks_per_s: must be at most 10000, got 20000.0"),
    ("max_frames_per_s = inf", "policy.max_frames_per_s: must be a finite number of at most "
                               "100000"),
    ("max_frames_per_s = 1e308", "policy.max_frames_per_s: must be at most 100000"),
    ("max_frames_per_s = 0.001", "policy.max_frames_per_s: must be at least 1"),
    ("max_requests_in_flight = 100000000", "policy.max_requests_in_flight: must be at most 64"),
    ("max_requests_in_flight = 1e8", "policy.max_requests_in_flight: expected int"),
    ("admissions_per_period = 1000000", "policy.admissions_per_period: must be at most 64"),
    ("request_timeout_ms = 1e300", "policy.request_timeout_ms: must be at most 60000"),
    ("request_timeout_ms = nan", "policy.request_timeout_ms: must be a finite number"),
    ("heartbeat_interval_ms = inf", "policy.heartbeat_interval_ms: must be a finite number"),
    ("heartbeat_interval_ms = 1e-9", "policy.heartbeat_interval_ms: must be at least 1"),
    ("heartbeat_timeout_ms = inf", "policy.heartbeat_timeout_ms: must be a finite number of at "
                                   "most"),
    ("heartbeat_timeout_ms = nan", "policy.heartbeat_timeout_ms: must be a finite number"),
    ("heartbeat_timeout_ms = 3600000", "policy.heartbeat_timeout_ms: must be at most 60000"),
    ("heartbeat_timeout_ms = 50", "policy: heartbeat_timeout_ms (50.0) must be longer than "
                                  "heartbeat_interval_ms"),
    ("admissions_per_period = 0", "policy.admissions_per_period: must be at least 1, got 0"),
    ("max_frame_bytes = 0", "policy.max_frame_bytes: must be at least 1, got 0"),
    ("mystery = 1", "policy.mystery: unknown key"),
    ('protocol = "grpc"', "policy.protocol: unknown value 'grpc' (expected one of warden, "
     "openpi)"),
    ('protocol = "openpi"', 'policy.openpi: required with protocol = "openpi"'),
    ('openpi = { policy_checkpoint = "pi05" }', 'policy.openpi: only with protocol = "openpi"'),
    ('protocol = "openpi"\nopenpi = { policy_checkpoint = "pi05" }',
     'policy.launch: must be false with protocol = "openpi"'),
    ('protocol = "openpi"\nopenpi = 3', "policy.openpi: expected a table, got 3"),
    ('protocol = "openpi"\nopenpi = { policy_checkpoint = "pi05", colour = 1 }',
     "policy.openpi.colour: unknown key"),
    ('protocol = "openpi"\nopenpi = { policy_checkpoint = "" }',
     "policy.openpi.policy_checkpoint: must not be empty"),
]


@pytest.mark.parametrize(("line", "needle"), POLICY, ids=[line for line, _ in POLICY])
@pytest.mark.usefixtures("nothing_starts", "no_emulator_starts")
def test_an_absurd_policy_link_limit_exits_2_before_anything_starts(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], line: str, needle: str) -> None:
    code, err, runs = _run(tmp_path, "sim-ur5e.toml", ("[policy]", f"[policy]\n{line}"), capsys)
    _assert_refused(code, err, runs, tmp_path / "cell.toml", needle)


CANOPEN_COUNTS = "counts_per_rev = [8388608.0, 8388608.0, 8388608.0, 8388608.0, 8388608.0, "
DRIVER = [
    # CiA 402: scales and timeouts
    ("sim-canopen.toml", (CANOPEN_COUNTS, "counts_per_rev = [inf, 8388608.0, 8388608.0, "
                          "8388608.0, 8388608.0, "),
     "driver.counts_per_rev[0]: must be a finite number"),
    ("sim-canopen.toml", (CANOPEN_COUNTS, "counts_per_rev = [nan, 8388608.0, 8388608.0, "
                          "8388608.0, 8388608.0, "), "counts_per_rev[0]"),
    ("sim-canopen.toml", (CANOPEN_COUNTS, "counts_per_rev = [1e300, 8388608.0, 8388608.0, "
                          "8388608.0, 8388608.0, "), "counts_per_rev[0]"),
    ("sim-canopen.toml", (CANOPEN_COUNTS, "counts_per_rev = [4096.5, 8388608.0, 8388608.0, "
                          "8388608.0, 8388608.0, "), "counts_per_rev[0]"),
    ("sim-canopen.toml", ("sdo_timeout_s = 1.0", "sdo_timeout_s = nan"),
     "driver.sdo_timeout_s: must be a finite number of at most 60, got nan"),
    ("sim-canopen.toml", ("sdo_timeout_s = 1.0", "sdo_timeout_s = inf"), "sdo_timeout_s"),
    ("sim-canopen.toml", ("state_timeout_s = 2.0", "state_timeout_s = nan"), "state_timeout_s"),
    ("sim-canopen.toml", ("state_timeout_s = 2.0", "state_timeout_s = 1e300"), "state_timeout_s"),
    ("sim-canopen.toml", ("tpdo_timeout_ms = 400", "tpdo_timeout_ms = 9000000000"),
     "tpdo_timeout_ms"),
    ("sim-canopen.toml", ("sdo_timeout_s = 1.0", "sdo_timeout_s = 1.0\nboot_timeout_s = inf"),
     "boot_timeout_s"),
    ("sim-canopen.toml", ("sdo_timeout_s = 1.0", "sdo_timeout_s = 1.0\ncall_timeout_s = nan"),
     "call_timeout_s"),
    ("sim-canopen.toml", ("sdo_timeout_s = 1.0", "sdo_timeout_s = 1.0\ngear_ratio = "
                          "[nan, 1, 1, 1, 1, 1]"), "gear_ratio[0]"),
    ("sim-canopen.toml", ("sdo_timeout_s = 1.0", "sdo_timeout_s = 1.0\noffset_counts = "
                          "[0, 0, 0, 0, 0, 1099511627776]"), "offset_counts[5]"),
    ("sim-canopen.toml", ("sdo_timeout_s = 1.0", "sdo_timeout_s = 1.0\nbitrate = 0"), "bitrate"),
    # Dynamixel: the baud rate, and the other numbers
    ("sim-dynamixel.toml", ("baud = 1000000", "baud = 0"), "baud: 0 is not a rate"),
    ("sim-dynamixel.toml", ("baud = 1000000", "baud = 99999999999999"), "baud: 99999999999999"),
    ("sim-dynamixel.toml", ("baud = 1000000", "baud = 19200"), "baud: 19200"),  # SDK only
    ("sim-dynamixel.toml", ("baud = 1000000", "baud = 4500000"), "baud: 4500000"),  # X only
    ("sim-dynamixel.toml", ("latency_budget_ms = 100", "latency_budget_ms = inf"),
     "latency_budget_ms: must be a finite number"),
    ("sim-dynamixel.toml", ("call_timeout_s = 1.0", "call_timeout_s = nan"), "call_timeout_s"),
    ("sim-dynamixel.toml", ("call_timeout_s = 1.0", "call_timeout_s = 1e300"), "call_timeout_s"),
    ("sim-dynamixel.toml", ("retries = 2", "retries = 1000000000"), "retries: must be at most"),
    ("sim-dynamixel.toml", ("watchdog_periods = 10", "watchdog_periods = 9000000000000"),
     "watchdog_periods: must be at most"),
    ("sim-dynamixel.toml", ("retries = 2", "retries = 2\noffsets_rad = [nan, 0, 0, 0, 0, 0]"),
     "offsets_rad"),
    ("sim-dynamixel.toml", ("retries = 2", "retries = 2\ncurrent_unit_ma = 5e-324"),
     "current_unit_ma"),
    ("sim-dynamixel.toml", ("retries = 2", "retries = 2\ntorque_per_amp_nm = inf"),
     "torque_per_amp_nm"),
    ("sim-dynamixel.toml", ("retries = 2", "retries = 2\ngripper_current_ma = 1e307"),
     "gripper_current_ma"),
    # UR: the gripper's feedback readings, and a regression on a float already bounded
    ("sim-ur5e-rtde.toml", ("gripper_feedback_open = 10.0", "gripper_feedback_open = 1e308"),
     "driver.gripper_feedback_open: must be at most 100, got 1e+308"),
    ("sim-ur5e-rtde.toml", ("servo_gain = 600", "servo_gain = nan"),
     "driver.servo_gain: must be a finite number of at most 2000, got nan"),
]


@pytest.mark.parametrize(("manifest", "change", "needle"), DRIVER,
                         ids=[f"{m.split('.')[0]}:{c[1].splitlines()[-1][:32]}"
                              for m, c, _ in DRIVER])
@pytest.mark.usefixtures("no_emulator_starts")
def test_an_absurd_driver_setting_exits_2_before_its_emulator_starts(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], manifest: str,
        change: tuple[str, str], needle: str) -> None:
    code, err, runs = _run(tmp_path, manifest, change, capsys)
    _assert_refused(code, err, runs, tmp_path / "cell.toml", needle)
    assert f"{tmp_path / 'cell.toml'}: driver" in err, err


@pytest.mark.usefixtures("no_emulator_starts")
def test_a_bad_driver_setting_on_a_real_device_exits_2_before_connecting(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = (MANIFESTS / "sim-dynamixel.toml").read_text()
    text = text.replace('name = "dynamixel"', 'name = "dynamixel"\nport = "/dev/ttyUSB0"', 1)
    text = text.replace('plant = "mujoco"', "launch = false", 1)
    text = text.replace("cycle_timeout_s = 30.0", "cycle_timeout_s = 30.0\n"
                        "simulated_operator = false", 1)
    assert "launch = false" in text and "simulated_operator = false" in text
    path = tmp_path / "cell.toml"
    path.write_text(text.replace("baud = 1000000", "baud = 0", 1))
    runs = tmp_path / "runs"
    code = main(["run", str(path), "--journal-dir", str(runs)])
    _assert_refused(code, capsys.readouterr().err, runs, path, "driver: baud: 0 is not a rate")


def test_the_dynamixel_baud_rates_open_in_the_sdk_and_the_emulator() -> None:
    """``BAUD_RATES`` is a constant so that settings need not import the SDK: it must stay
    within what the SDK's PortHandler opens and what the bus emulator speaks."""
    from dynamixel_sdk import PortHandler

    port = PortHandler("/dev/null")  # getCFlagBaud only looks the rate up
    for rate in BAUD_RATES:
        assert rate in SDK_BAUD_RATES and port.getCFlagBaud(rate) == rate
        assert rate in BAUD_CODES
    assert 1_000_000 in BAUD_RATES and 4_500_000 not in BAUD_RATES


def test_a_period_the_simulated_plant_cannot_step_exits_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The simulated world steps its plant a whole number of 2 ms steps per control period."""
    code, err, runs = _run(tmp_path, "sim-ur5e.toml",
                           ("control_period_ms = 2\n", "control_period_ms = 2.5\n"), capsys)
    _assert_refused(code, err, runs, tmp_path / "cell.toml",
                    "timing.control_period_ms: 2.5 ms is not a whole number")
