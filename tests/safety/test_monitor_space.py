"""The monitor's space check: the measured arm against ``[geometry]``'s keep-out zones and
obstacles, judged by an oracle that shares none of the monitor's code.

The monitor places the arm with MuJoCo and measures with MuJoCo's collision detection
(kernel/safety/space.py). The oracle here is Pinocchio's forward kinematics of the same model
file (the TCP, each body's origin) and plain geometry: a box around the TCP holds the pads (the
TCP lies on their inner faces), and with the tool pointing straight down the pads' tips are the
arm's lowest points, 12.5 mm below the TCP (ur5e.xml: pad centre 0.115 m, half length 0.025 m,
TCP 0.1275 m from the gripper's origin).
"""

from __future__ import annotations

import itertools
import math
import os
import tomllib
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from kernel.cell_geometry import GeometrySettings, geometry_table
from kernel.model_file import BUILTIN
from kernel.safety.checks import Breach, Limits, Sample
from kernel.safety.heartbeat import HeartbeatReceiver
from kernel.safety.monitor import Monitor
from kernel.safety.service import StartError, plan
from kernel.safety.settings import SafetySettings
from kernel.safety.space import SpaceCheck, clearance_of
from kernel.safety.view import ViewError, read_view
from kernel.scenario.fields import Where
from tests.safety.support import MANIFESTS, free_port, safety_table
from tests.safety.test_monitor import Clock, ScriptedWatch

ARM = BUILTIN["ur5e"]
HOME = (0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)
"""Upright arm, tool straight down; wrist 1 = -pi/2 - lift - elbow keeps it down."""
PAD_TIP_BELOW_TCP = 0.0125
TABLE = """
[[geometry.obstacles]]
name = "table"
shape = "box"
size = [0.6, 0.6, 0.025]
position = [-0.35, 0.0, -0.025]
"""


def geometry(text: str) -> GeometrySettings:
    read = geometry_table(tomllib.loads("[geometry]\n" + text), Where("cell.toml", ""))
    assert read is not None
    return read


def box(name: str, centre: np.ndarray, half: float, table: str = "keep_out",
        extra: str = "") -> str:
    return (f'\n[[geometry.{table}]]\nname = "{name}"\nshape = "box"\n'
            f"size = [{half}, {half}, {half}]\nposition = [{', '.join(map(str, centre))}]\n"
            + extra)


class Oracle:
    """Pinocchio's forward kinematics of the arm's model file."""

    def __init__(self) -> None:
        self.model = pin.buildModelFromMJCF(str(ARM.path))
        self.data = self.model.createData()
        self.bodies = [self.model.getFrameId(name) for name in (
            "shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link",
            "wrist_3_link", "gripper", "tcp")]

    def _place(self, q: tuple[float, ...]) -> None:
        full = np.zeros(self.model.nq)
        full[:6] = q
        pin.framesForwardKinematics(self.model, self.data, full)

    def tcp(self, q: tuple[float, ...]) -> pin.SE3:
        self._place(q)
        return self.data.oMf[self.model.getFrameId("tcp")].copy()

    def chain(self, q: tuple[float, ...]) -> np.ndarray:
        """The body origins from the shoulder to the TCP, in order."""
        self._place(q)
        return np.array([self.data.oMf[f].translation for f in self.bodies])


@pytest.fixture(scope="module")
def oracle() -> Oracle:
    return Oracle()


def _segment_distance(point: np.ndarray, chain: np.ndarray) -> float:
    best = math.inf
    for a, b in itertools.pairwise(chain):
        ab = b - a
        t = 0.0 if not ab.any() else float(np.clip((point - a) @ ab / (ab @ ab), 0.0, 1.0))
        best = min(best, float(np.linalg.norm(point - (a + t * ab))))
    return best


FAR = 0.05 * math.sqrt(3) + 0.25
"""A box of half size 0.05 whose centre is this far from every segment between the body
origins cannot touch the arm: no geom of ur5e.xml reaches 0.2 m from that chain (the
shoulder's offset 0.138 m plus its radius 0.054 m is the widest)."""


def test_a_keep_out_box_around_the_tcp_is_a_breach_and_one_far_from_the_arm_is_not(
        oracle: Oracle) -> None:
    rng = np.random.default_rng(17)
    checked = 0
    for _ in range(60):
        q = tuple(rng.uniform(-math.pi, math.pi, 6).tolist())
        around = oracle.tcp(q).translation
        inside = SpaceCheck(ARM, 6, geometry(box("zone", around, 0.05)))
        [found] = inside.findings(q)
        assert found.breach is Breach.SPACE and "keep-out zone 'zone'" in found.detail
        chain = oracle.chain(q)
        far = next((p for p in rng.uniform(-1.2, 1.2, (200, 3))
                    if _segment_distance(p, chain) > FAR), None)
        if far is not None:
            checked += 1
            assert SpaceCheck(ARM, 6, geometry(box("zone", far, 0.05))).findings(q) == []
    assert checked > 40


def _tool_down(lift: float, elbow: float) -> tuple[float, ...]:
    return (0.0, lift, elbow, -math.pi / 2 - lift - elbow, -math.pi / 2, 0.0)


def _lowered(oracle: Oracle, pad_tip_z: float) -> tuple[float, ...]:
    """A tool-down configuration whose pads' tips are at ``pad_tip_z`` (Pinocchio FK, a
    bisection on the elbow from the upright pose)."""
    low, high = math.pi / 2, 3.05  # the elbow bends further: the TCP goes down
    for _ in range(60):
        middle = (low + high) / 2
        z = oracle.tcp(_tool_down(-math.pi / 2, middle)).translation[2] - PAD_TIP_BELOW_TCP
        low, high = (middle, high) if z > pad_tip_z else (low, middle)
    q = _tool_down(-math.pi / 2, low)
    placed = oracle.tcp(q)
    assert placed.rotation[:, 2] @ np.array([0.0, 0.0, -1.0]) > 1 - 1e-9  # straight down
    assert abs(placed.translation[2] - PAD_TIP_BELOW_TCP - pad_tip_z) < 1e-6
    # Every body from the upper arm to the wrist is well above; the shoulder's origin is on
    # the base plane, its capsule's lowest point 0.03 m above it.
    assert oracle.chain(q)[1:-2, 2].min() > 0.1
    return q


@pytest.mark.parametrize(("pad_tip_z", "breach"), [
    (0.2, False), (0.012, False), (0.008, True), (0.0, True), (-0.03, True)])
def test_an_obstacle_is_kept_at_the_clearance(oracle: Oracle, pad_tip_z: float,
                                              breach: bool) -> None:
    check = SpaceCheck(ARM, 6, geometry("margin_m = 0.01\n" + TABLE))
    found = check.findings(_lowered(oracle, pad_tip_z))
    if not breach:
        assert found == []
        return
    [finding] = found
    assert finding.breach is Breach.SPACE
    assert finding.detail.startswith("finger_")
    assert finding.detail.endswith("obstacle 'table' (clearance 0.01 m)")
    measured = float(finding.detail.split(" m ")[0].rsplit(" ", 1)[1])
    assert measured == pytest.approx(abs(pad_tip_z), abs=1.5e-3)


def test_the_clearance_is_the_smallest_any_phase_keeps(oracle: Oracle) -> None:
    loose = geometry("margin_m = 0.01\n[geometry.phase_margin_m]\nFREE_SPACE = 0.03\n"
                     "CONTACT = 0.0\n" + TABLE)
    assert clearance_of(loose) == 0.0
    q = _lowered(oracle, 0.005)
    assert SpaceCheck(ARM, 6, loose).findings(q) == []
    assert SpaceCheck(ARM, 6, geometry("margin_m = 0.01\n" + TABLE)).findings(q) != []


def test_an_obstacle_some_phase_may_touch_is_kept_from_the_links_not_the_tool(
        oracle: Oracle) -> None:
    """A box of half size 0.05 around the TCP holds the pads and nothing of the links (the
    wrist's sensor housing ends at the gripper's origin, 0.1275 m above the TCP); one around
    the gripper's origin holds the end of the wrist's housing too."""
    q = HOME
    tcp = oracle.tcp(q)
    touchable = 'allow_contact = ["CONTACT"]\n'
    around_tcp = box("fixture", tcp.translation, 0.05, "obstacles", touchable)
    assert SpaceCheck(ARM, 6, geometry(around_tcp)).findings(q) == []
    untouchable = box("fixture", tcp.translation, 0.05, "obstacles")
    [finding] = SpaceCheck(ARM, 6, geometry(untouchable)).findings(q)
    assert finding.detail.startswith("finger_")
    gripper_origin = tcp.translation - tcp.rotation[:, 2] * 0.1275
    around_wrist = box("fixture", gripper_origin, 0.05, "obstacles", touchable)
    [finding] = SpaceCheck(ARM, 6, geometry(around_wrist)).findings(q)
    assert finding.detail.startswith("wrist_3_link is ")


def test_a_solid_is_placed_and_turned_as_the_manifest_says(oracle: Oracle) -> None:
    """The rotation is roll, pitch, yaw about the fixed axes: Pinocchio's rpyToMatrix."""
    rotation = (0.3, -1.1, 2.2)
    text = ('\n[[geometry.keep_out]]\nname = "slab"\nshape = "box"\nsize = [0.3, 0.02, 0.1]\n'
            f"position = [0.4, 0.5, 0.6]\nrotation = [{', '.join(map(str, rotation))}]\n")
    check = SpaceCheck(ARM, 6, geometry(text))
    check.findings(HOME)  # places everything
    slab = check.model.geom("warden-safety/slab").id
    assert np.allclose(check.data.geom_xmat[slab].reshape(3, 3),
                       pin.rpy.rpyToMatrix(*rotation), atol=1e-9)
    assert np.allclose(check.data.geom_xpos[slab], [0.4, 0.5, 0.6])


def test_a_reading_that_is_not_a_configuration_is_left_to_the_joint_checks() -> None:
    check = SpaceCheck(ARM, 6, geometry(TABLE))
    assert check.findings((0.0,) * 5) == []
    assert check.findings((math.nan, *HOME[1:])) == []


# -- in the monitor --------------------------------------------------------------------------

def test_the_monitor_stops_the_arm_entering_a_keep_out_zone_and_reports_it(
        oracle: Oracle, tmp_path: Path) -> None:
    settings = SafetySettings(max_wrist_force_n=50.0)
    limits = Limits(lower=(-7.0,) * 6, upper=(7.0,) * 6, velocity=(4.0,) * 6, max_force_n=50.0,
                    position_margin=0.0, velocity_margin=0.0)
    reaching = (0.0, -1.2, 1.5, -1.87, -1.57, 0.0)
    zone = SpaceCheck(ARM, 6, geometry(box("bench", oracle.tcp(reaching).translation, 0.05)))
    watch, clock = ScriptedWatch(), Clock()
    receiver = HeartbeatReceiver(tmp_path / "hb.sock", os.getegid(),
                                 settings.heartbeat_timeout_ns, settings.closing_timeout_ns)
    try:
        monitor = Monitor(settings, limits, watch, receiver, clock, space=zone)
        watch.reading = Sample(q=HOME, qd=(0.0,) * 6, force_n=0.0)
        monitor.check()
        assert watch.stops == 0 and monitor.status()["ok"]
        assert monitor.status()["space"] == ["bench"]
        watch.reading = Sample(q=reaching, qd=(0.0,) * 6, force_n=0.0)
        clock.advance(4)
        monitor.check()
        assert watch.stops == 1
        status = monitor.status()
        assert not status["ok"] and status["problems"][0].startswith("space: ")
        assert "inside keep-out zone 'bench'" in status["last_stop"]["violations"][0]
        watch.reading = Sample(q=HOME, qd=(0.0,) * 6, force_n=0.0)  # brought back out
        clock.advance(4)
        monitor.check()
        assert monitor.status()["ok"] and watch.stops == 1
    finally:
        receiver.close()


# -- the monitor's own view: the model file and [geometry] -----------------------------------

@pytest.mark.parametrize("path", sorted(MANIFESTS.glob("*.toml")), ids=lambda p: p.name)
def test_the_view_finds_the_model_file_warden_loads(path: Path, tmp_path: Path) -> None:
    from kernel.config.kinematics import model_spec

    text = path.read_text()
    spec = model_spec(tomllib.loads(text)["robot"], Where(str(path), "robot"))
    if "[geometry]" not in text:
        text += "\n[geometry]\n" + TABLE
    copy = tmp_path / path.name  # beside nothing: a relative model path is the manifest's
    copy.write_text(text.replace('model = "', f'model = "{path.parent}/'))
    view = read_view(copy)
    if spec is None:
        assert view.arm_model is None
    else:
        assert view.arm_model is not None
        assert (view.arm_model.path, view.arm_model.tcp_frame, view.arm_model.joints) == (
            spec.path, spec.tcp_frame, spec.joints)


def test_without_geometry_the_view_reads_no_model(tmp_path: Path) -> None:
    """The model is the space check's: without [geometry] a mistake naming it is warden's to
    refuse, and the monitor watches the joints as before; with it, the monitor refuses it
    with warden's message."""
    text = (MANIFESTS / "sim-ur5e.toml").read_text().split("\n[geometry]")[0].replace(
        'kinematics = "ur5e"', 'kinematics = "no-such-model"')
    path = tmp_path / "cell.toml"
    path.write_text(text)
    assert read_view(path).arm_model is None
    path.write_text(text + "\n[geometry]\n" + TABLE)
    with pytest.raises(ViewError, match=r"cell.toml: robot.kinematics: unknown model "
                       r"'no-such-model' \(expected one of ur5e\)"):
        read_view(path)


def _sim_cell(tmp_path: Path, geometry: str = "", robot: tuple[str, str] = ("", "")) -> Path:
    """The simulated cell's manifest for the monitor, with ``geometry`` as its only
    ``[geometry]`` (the shipped one ends with its own, which is left out)."""
    text = (MANIFESTS / "sim-ur5e.toml").read_text().split("\n[geometry]")[0]
    path = tmp_path / "cell.toml"
    path.write_text(text.replace(*robot) + safety_table(tmp_path, sim_port=free_port())
                    + (f"\n[geometry]\n{geometry}" if geometry else ""))
    return path


def test_a_monitor_with_solids_and_no_model_is_refused(tmp_path: Path) -> None:
    manifest = _sim_cell(tmp_path, TABLE, robot=('kinematics = "ur5e"', ""))
    with pytest.raises(StartError, match=r"cell.toml: robot.kinematics: the monitor checks the "
                       r"arm against \[geometry\] and needs the arm's model"):
        plan(str(manifest))


def test_a_monitor_with_geometry_checks_space(tmp_path: Path) -> None:
    chosen = plan(str(_sim_cell(tmp_path, TABLE)))
    assert chosen.space is not None and chosen.space.solids == ("table",)
    assert plan(str(_sim_cell(tmp_path))).space is None


# -- in a running cell: warden drives the UR emulator, the monitor watches its own copy ------

ABOVE_PART = (-0.40, 0.10, 0.10)
"""On the pick descent: the TCP goes from 0.1475 m above the table (the pads' tips 1 cm above
the zone) down to 0.0475 m over the part at (-0.40, 0.10) (skills/assembly.py: pick approach,
then descend)."""
ZONE_RADIUS = 0.025
GRASP_TCP_Z = 0.0475


@pytest.mark.slow
def test_a_ur_arm_entering_a_keep_out_zone_is_stopped_through_the_dashboard(
        tmp_path: Path, oracle: Oracle) -> None:
    """warden runs the shipped UR cell; the monitor's copy of its manifest adds a keep-out
    sphere on the pick descent. The monitor stops the program before the TCP reaches the part
    (the oracle: Pinocchio FK of the emulator's own joint positions)."""
    from stubs.ur_controller.launch import EmulatedController
    from tests.safety.support import Monitor, Warden, ur_manifest, wait_for
    from tests.safety.test_safety_cells import UR_DEVICE_TIMEOUT_MS, Arm

    with EmulatedController(plant="kinematic") as emulator:
        arm = Arm(emulator)
        manifest = ur_manifest(tmp_path, emulator.host, device_timeout_ms=UR_DEVICE_TIMEOUT_MS)
        zone = manifest.with_name("zone.toml")
        zone.write_text(manifest.read_text() + (
            '\n[[geometry.keep_out]]\nname = "above_part"\nshape = "sphere"\n'
            f"size = [{ZONE_RADIUS}]\nposition = [{', '.join(map(str, ABOVE_PART))}]\n"))
        monitor = Monitor(zone, tmp_path)
        warden: Warden | None = None
        lowest = math.inf
        try:
            assert "above_part" in monitor.wait_connected()["space"]
            warden = Warden(manifest, tmp_path)  # warden's own manifest has no such zone

            def stopped() -> bool:
                nonlocal lowest
                assert warden is not None and warden.alive(), warden and warden.log_path.read_text()
                lowest = min(lowest, oracle.tcp(tuple(arm.truth()["q"])).translation[2])
                return arm.stopped_at_rest()

            wait_for(stopped, "the monitor's stop", timeout_s=60, poll_s=0.002)
            final = oracle.tcp(tuple(arm.truth()["q"])).translation
        finally:
            if warden is not None:
                warden.stop()
            assert monitor.stop() == 0
    first = monitor.first_stop()
    print(f"stopped with the TCP at {final.round(4).tolist()}, lowest seen {lowest:.4f} m: "
          f"{first['violations']}")
    assert first["violations"][0].startswith("space: ")
    assert "inside keep-out zone 'above_part'" in first["violations"][0]
    assert first["answer"] == "dashboard answered 'Stopped'"
    # Stopped at the zone: no point of the tool is further than 0.1 m from the TCP (the
    # gripper body's far corner), plus a few millimetres of stopping travel.
    assert np.linalg.norm(final - ABOVE_PART) < ZONE_RADIUS + 0.1 + 0.01
    assert lowest > GRASP_TCP_Z + 0.01  # never reached the part
