"""`warden check` against every driver's emulator, as an integrator runs it against an arm: a
signed manifest with ``[emulator] launch = false`` naming the device's address, the command line
in process, the emulator a separate process on the driver's real transport.

Every emulator counts the commands that could move its arm (UR: motion commands the control
script executed; Dynamixel: goal writes with torque on; CiA 402: new targets while following,
or enabling with a target away from the axis). After a check every count is zero; after one
setpoint through the same driver it is not, so the zero means something. Each driver also has a
NOT READY case: the device configured otherwise than the manifest says.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from drivers.base import Command, CommandKind
from kernel.app.check import check_device, load_checked
from kernel.app.device import driver_from_manifest
from kernel.app.session import control_config
from kernel.cli import main
from kernel.manifest import Manifest, load_manifest
from kernel.signing import generate_keypair, sign
from stubs.cell.emulated import LAUNCHERS
from stubs.cell.sim_world import SimWorld
from stubs.fault_control import inject
from stubs.plant.mujoco_plant import MujocoPlant
from stubs.process import EmulatorProcess
from tests.cell.harness import MANIFESTS
from tests.drivers.support import active

pytestmark = pytest.mark.slow

SHIPPED = {"ur_rtde": "sim-ur5e-rtde.toml", "dynamixel": "sim-dynamixel.toml",
           "canopen402": "sim-canopen.toml"}
SECONDS = "1"


@pytest.fixture
def keys(tmp_path: Path) -> tuple[Path, Path]:
    """(private key, trusted keys directory)."""
    trusted = tmp_path / "trusted"
    trusted.mkdir()
    generate_keypair(tmp_path / "signer.key", trusted / "signer.pub")
    return tmp_path / "signer.key", trusted


class Device:
    """One driver's emulator process, started as the cell's launcher starts it."""

    def __init__(self, driver: str, extra: tuple[str, ...] = ()) -> None:
        launch = LAUNCHERS[driver](load_manifest(MANIFESTS / SHIPPED[driver]), "kinematic")
        self.process = EmulatorProcess(launch.module, *launch.args, *extra).start()
        ready = self.process.info
        self.settings: dict[str, Any] = launch.settings(ready)
        self.control = (launch.control_host(ready),
                        int(ready.get("control_port", ready.get("fault_port"))))

    def motion_commands(self) -> int:
        return int(inject(self.control, "motion")["motion_commands"])


@contextlib.contextmanager
def device(driver: str, extra: tuple[str, ...] = ()) -> Iterator[Device]:
    started = Device(driver, extra)
    try:
        yield started
    finally:
        started.process.stop()


def manifest_for(tmp_path: Path, driver: str, settings: dict[str, Any],
                 keys: tuple[Path, Path] | None, edits: dict[str, str] | None = None) -> Path:
    """The shipped manifest of ``driver`` as a real device's: the emulator's address in
    ``[driver]``, nothing launched, no simulated operator; signed when ``keys`` are given."""
    text = (MANIFESTS / SHIPPED[driver]).read_text()
    lines = "".join(f"{key} = {json.dumps(value)}\n" for key, value in settings.items())
    text = text.replace("[driver]\n", f"[driver]\n{lines}", 1)
    text = text.replace("[emulator]\n", "[emulator]\nlaunch = false\n", 1)
    text = text.replace("[cell]\n", "[cell]\nsimulated_operator = false\n", 1)
    for old, new in (edits or {}).items():
        assert old in text, f"{old!r} is not in {SHIPPED[driver]}"
        text = text.replace(old, new, 1)
    path = tmp_path / "cell.toml"
    path.write_text(text)
    if keys is not None:
        sign(path, keys[0])
    return path


def check(path: Path, keys: tuple[Path, Path], tmp_path: Path, *extra: str
          ) -> tuple[int, dict[str, Any]]:
    out = tmp_path / "check.json"
    code = main(["check", str(path), "--keys", str(keys[1]), "--seconds", SECONDS,
                 "--json", str(out), *extra])
    return code, json.loads(out.read_text()) if out.exists() else {}


def rows(report: dict[str, Any], verdict: str) -> dict[str, dict[str, Any]]:
    return {row["name"]: row for row in report["findings"] if row["verdict"] == verdict}


async def _one_setpoint(manifest: Manifest) -> None:
    """One position setpoint a hundredth of a radian away on joint 0, through the driver."""
    driver = driver_from_manifest(manifest, manifest.driver_settings)
    async with active(driver, control_config(manifest.core)) as managed:
        q = list((await managed.read()).q)
        q[0] += 0.01
        applied = await managed.write(Command(kind=CommandKind.POSITION, q=tuple(q)))
        assert applied.accepted
        await asyncio.sleep(0.1)


DRIVER_ROWS = {
    "ur_rtde": ("robot mode", "safety status", "control script (runtime state)",
                "speed slider, speed scaling", "gripper opening (standard_analog_input0)"),
    "dynamixel": ("model number (0)", "operating mode (11)", "position limits (52, 48)",
                  "homing offset (20), drive mode (10)", "profile velocity (112)",
                  "torque (64), hardware error (70)", "gripper opening"),
    "canopen402": ("modes (0x6502, 0x6061)", "drive state (statusword)",
                   "software position limits (0x607D)", "max profile velocity (0x607F)",
                   "position scale (0x608F x 0x6091)", "gripper opening"),
}


@pytest.mark.parametrize("driver", sorted(SHIPPED))
def test_a_device_that_agrees_with_the_manifest_is_ready_and_never_moved(
        tmp_path: Path, keys: tuple[Path, Path], driver: str) -> None:
    with device(driver) as emulated:
        path = manifest_for(tmp_path, driver, emulated.settings, keys)
        code, report = check(path, keys, tmp_path)
        assert rows(report, "NOT READY") == {}
        assert code == 0
        ready = rows(report, "READY")
        for name in ("manifest signature", "device: connect", "device: configure",
                     "device: activate", "state samples", "joint positions",
                     "at rest while held", "device: deactivate", "device: close",
                     *DRIVER_ROWS[driver]):
            assert name in ready, f"{name!r} missing: {sorted(ready)}"
        assert "motion" in rows(report, "NOT EXERCISED")
        assert emulated.motion_commands() == 0
        # The counter counts: one setpoint through the same driver is motion to the device.
        asyncio.run(_one_setpoint(load_manifest(path)))
        assert emulated.motion_commands() > 0


def test_ur_a_controller_that_scales_motion_down_is_not_ready(
        tmp_path: Path, keys: tuple[Path, Path]) -> None:
    with device("ur_rtde") as emulated:
        inject(emulated.control, "speed_scaling", value=0.5)
        code, report = check(manifest_for(tmp_path, "ur_rtde", emulated.settings, keys), keys,
                             tmp_path)
        assert code == 1
        assert set(rows(report, "NOT READY")) == {"speed slider, speed scaling"}
        assert "scales motion to 50 %" in rows(report, "NOT READY")[
            "speed slider, speed scaling"]["reason"]
        assert emulated.motion_commands() == 0


def _prepare_servos(port: str) -> None:
    """What an integrator's Dynamixel Wizard session would leave: servo 3's Max Position Limit
    lowered and servo 2 given a Homing Offset (EEPROM, torque off), joint 0 turned to 0.5 rad
    and let go."""
    bus, handler = PortHandler(port), PacketHandler(2.0)
    assert bus.openPort() and bus.setBaudRate(1_000_000)
    try:
        assert handler.write4ByteTxRx(bus, 3, 48, 3500)[0] == COMM_SUCCESS
        assert handler.write4ByteTxRx(bus, 2, 20, 65)[0] == COMM_SUCCESS
        assert handler.write1ByteTxRx(bus, 1, 64, 1)[0] == COMM_SUCCESS
        goal = 2048 + round(0.5 * 4096 / (2 * math.pi))
        assert handler.write4ByteTxRx(bus, 1, 116, goal)[0] == COMM_SUCCESS
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            position, result, _ = handler.read4ByteTxRx(bus, 1, 132)
            if result == COMM_SUCCESS and abs(position - goal) <= 1:
                break
            time.sleep(0.01)
        assert abs(position - goal) <= 1, f"joint 0 at tick {position}, not {goal}"
        assert handler.write1ByteTxRx(bus, 1, 64, 0)[0] == COMM_SUCCESS
    finally:
        bus.closePort()


def test_dynamixel_servos_set_otherwise_than_the_manifest_are_not_ready(
        tmp_path: Path, keys: tuple[Path, Path]) -> None:
    """A servo limit narrower than the manifest's, a joint outside the manifest's limits, and a
    joint calibrated twice (the servo's Homing Offset and the manifest's offsets_rad)."""
    with device("dynamixel") as emulated:
        _prepare_servos(emulated.settings["port"])
        before = emulated.motion_commands()
        settings = {**emulated.settings, "offsets_rad": [0.0, 0.1, 0.0, 0.0, 0.0, 0.0]}
        path = manifest_for(tmp_path, "dynamixel", settings, keys, edits={
            "position_limits = [[-3.14, 3.14]": "position_limits = [[-0.3, 0.3]"})
        code, report = check(path, keys, tmp_path)
        assert code == 1
        failed = rows(report, "NOT READY")
        assert set(failed) == {"position limits (52, 48)", "joint positions",
                               "homing offset (20), drive mode (10)"}
        assert "joint 2 (id 3)" in failed["position limits (52, 48)"]["reason"]
        assert failed["homing offset (20), drive mode (10)"]["reason"].startswith(
            "joint 1 (id 2): the servo shifts")
        assert "joint 0 (id 1)" not in failed["position limits (52, 48)"]["reason"]
        assert failed["joint positions"]["reason"].startswith("joint 0: at 0.49")
        assert emulated.motion_commands() == before


def test_a_device_that_reports_a_fault_at_connect_is_a_not_ready_row(
        tmp_path: Path, keys: tuple[Path, Path]) -> None:
    with device("ur_rtde") as emulated:
        inject(emulated.control, "protective_stop")
        code, report = check(manifest_for(tmp_path, "ur_rtde", emulated.settings, keys), keys,
                             tmp_path)
        assert code == 1
        failed = rows(report, "NOT READY")
        assert set(failed) == {"device: connect"}
        assert "PROTECTIVE_STOP" in failed["device: connect"]["reason"]
        assert "device: close" in rows(report, "READY")
        assert emulated.motion_commands() == 0


def test_canopen_a_drive_slower_than_the_manifest_is_not_ready(
        tmp_path: Path, keys: tuple[Path, Path]) -> None:
    with device("canopen402", ("--max-profile-velocity", "1.0")) as emulated:
        code, report = check(manifest_for(tmp_path, "canopen402", emulated.settings, keys),
                             keys, tmp_path)
        assert code == 1
        failed = rows(report, "NOT READY")
        assert set(failed) == {"max profile velocity (0x607F)"}
        assert "1 rad/s, below the manifest's 3.14 rad/s" in failed[
            "max profile velocity (0x607F)"]["reason"]
        assert emulated.motion_commands() == 0


class CountingPlant(MujocoPlant):
    """The sim driver's device: the in-process plant, counting every motion command."""

    motion_commands = 0

    def command_position(self, q: Any) -> None:
        self.motion_commands += 1
        super().command_position(q)

    def command_velocity(self, qd: Any) -> None:
        self.motion_commands += 1
        super().command_velocity(qd)

    def command_impedance(self, q: Any, stiffness: Any, damping: Any) -> None:
        self.motion_commands += 1
        super().command_impedance(q, stiffness, damping)

    def command_gripper(self, opening: float) -> None:
        self.motion_commands += 1
        super().command_gripper(opening)


def test_sim_the_plant_is_never_commanded(tmp_path: Path, keys: tuple[Path, Path]) -> None:
    path = tmp_path / "sim.toml"
    shutil.copyfile(MANIFESTS / "sim-ur5e.toml", path)
    sign(path, keys[0])
    manifest, signature = load_checked(path, keys[1])
    plant = CountingPlant()
    world = SimWorld(manifest.core.control_period_ns, plant)
    findings = asyncio.run(check_device(manifest, world, 1.0))
    assert signature.verdict == "READY"
    assert [f.name for f in findings if f.verdict == "NOT READY"] == []
    assert plant.motion_commands == 0


def test_sim_an_unsigned_manifest_is_checked_and_not_ready(
        tmp_path: Path, keys: tuple[Path, Path]) -> None:
    path = tmp_path / "sim.toml"
    shutil.copyfile(MANIFESTS / "sim-ur5e.toml", path)
    code, report = check(path, keys, tmp_path)
    assert code == 1
    assert set(rows(report, "NOT READY")) == {"manifest signature"}
    assert "not signed" in rows(report, "NOT READY")["manifest signature"]["reason"]
    assert "device: activate" in rows(report, "READY")


def test_a_signature_that_does_not_verify_exits_2_before_any_device_starts(
        tmp_path: Path, keys: tuple[Path, Path], capsys: pytest.CaptureFixture[str]) -> None:
    # Nothing listens at this address (emulators take 127.0.0.x): had check tried the device,
    # it would say so instead.
    path = manifest_for(tmp_path, "ur_rtde", {"host": "127.0.1.254", "reconnect_attempts": 0},
                        keys)
    path.write_text(path.read_text().replace("cycles = 3", "cycles = 2"))
    code, report = check(path, keys, tmp_path)
    assert (code, report) == (2, {})
    error = capsys.readouterr().err
    assert "the file changed after it was signed" in error and "dashboard" not in error


def test_an_unreachable_device_exits_2_naming_it(
        tmp_path: Path, keys: tuple[Path, Path], capsys: pytest.CaptureFixture[str]) -> None:
    path = manifest_for(tmp_path, "ur_rtde", {"host": "127.0.1.254", "reconnect_attempts": 0},
                        keys)
    code, report = check(path, keys, tmp_path)
    assert (code, report) == (2, {})
    error = capsys.readouterr().err
    assert "cannot start the device" in error and "127.0.1.254:29999" in error


@pytest.mark.parametrize("seconds", ["0", "601", "nan"])
def test_seconds_out_of_range_is_invalid_input(
        tmp_path: Path, keys: tuple[Path, Path], seconds: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "sim.toml"
    shutil.copyfile(MANIFESTS / "sim-ur5e.toml", path)
    code = main(["check", str(path), "--keys", str(keys[1]), "--seconds", seconds])
    assert code == 2
    assert "--seconds: must be 0.1 to 600" in capsys.readouterr().err
