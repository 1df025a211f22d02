"""The MuJoCo cell: model consistency, the three control modes, the wrist wrench, and a scripted
pick-and-insert that shows the 1.5 mm clearance hole is physically workable."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from assurance.kinematics import ArmKinematics, Pose
from skills.trajectory import MotionLimits, plan_joint_move
from stubs import robot_model as rm
from stubs.plant.base import Plant
from stubs.plant.mujoco_plant import ControlMode, MujocoPlant, MujocoPlantConfig, PlantDiverged
from stubs.robot_model.kinematics import arm_kinematics

DT = 0.002
HOME = np.array(rm.HOME_Q)
DOWN = np.array(rm.TOOL_DOWN_ROTATION)
HOLE = np.array(rm.HOLE_TOP_POSITION)
PEG_START = np.array(rm.PEG_START_POSITION)
# Compliant enough to let the peg find the hole, stiff enough to carry it (N·m/rad, N·m·s/rad).
INSERT_STIFFNESS = np.array([1500.0, 1500.0, 1000.0, 200.0, 200.0, 200.0])
INSERT_DAMPING = 2 * np.sqrt(INSERT_STIFFNESS * np.array([2.0, 2.0, 0.6, 0.15, 0.15, 0.12]))


@pytest.fixture(scope="module")
def kin() -> ArmKinematics:
    return arm_kinematics()


@pytest.fixture
def plant() -> MujocoPlant:
    return MujocoPlant()


def above(point: np.ndarray, height: float) -> np.ndarray:
    return np.asarray(point, dtype=float) + np.array([0.0, 0.0, height])


def q_of(plant: MujocoPlant) -> np.ndarray:
    return np.array(plant.state().q)


def move_to(plant: MujocoPlant, kin: ArmKinematics, tcp: np.ndarray, settle: int = 50) -> float:
    """Stream a joint move to the tool-down pose at ``tcp``; returns the worst tracking error."""
    solution = kin.solve(Pose(np.asarray(tcp, float), DOWN), q_of(plant))
    assert solution.converged, solution
    limits = MotionLimits(kin.lower, kin.upper, np.full(6, np.pi), np.full(6, 4.0),
                          np.full(6, 40.0))
    move = plan_joint_move(q_of(plant), solution.q, limits)
    worst = 0.0
    for tick in range(1, int(np.ceil(move.duration / DT)) + 1):
        setpoint = move.sample(tick * DT).position
        plant.command_position(setpoint)
        plant.step(1)
        worst = max(worst, float(np.abs(q_of(plant) - setpoint).max()))
    plant.step(settle)
    return worst


def descend_compliantly(plant: MujocoPlant, kin: ArmKinematics, xy: np.ndarray, z_from: float,
                        z_to: float, speed: float = 0.03, dwell_s: float = 1.0) -> None:
    """Lower the tool-down TCP in joint impedance mode, re-solving IK every tick."""
    q = q_of(plant)
    z = z_from
    for _ in range(int((z_from - z_to) / (speed * DT) + dwell_s / DT)):
        z = max(z - speed * DT, z_to)
        q = kin.solve(Pose(np.array([xy[0], xy[1], z]), DOWN), q).q
        plant.command_impedance(q, INSERT_STIFFNESS, INSERT_DAMPING)
        plant.step(1)


def test_cell_constants_match_the_compiled_model(plant):
    m, d = plant.model, plant.data
    np.testing.assert_allclose(d.site(rm.HOLE_SITE).xpos, HOLE, atol=1e-12)
    peg_qpos = m.jnt_qposadr[m.body(rm.PEG_BODY).jntadr[0]]
    np.testing.assert_allclose(m.qpos0[peg_qpos:peg_qpos + 3], PEG_START, atol=1e-12)
    np.testing.assert_allclose(m.geom(rm.PEG_GEOM).size, rm.PEG_HALF_EXTENTS)
    inner_faces = []
    for name, axis in zip(rm.FIXTURE_WALL_GEOMS, (0, 0, 1, 1), strict=True):
        wall = m.geom(name)
        inner_faces.append(abs(wall.pos[axis]) - wall.size[axis])
        assert wall.size[2] * 2 == pytest.approx(rm.HOLE_DEPTH)
    np.testing.assert_allclose(inner_faces, rm.HOLE_HALF_WIDTH, atol=1e-12)
    clearance = 2 * (rm.HOLE_HALF_WIDTH - rm.PEG_HALF_EXTENTS[0])
    assert 0.001 <= clearance <= 0.002
    assert m.actuator(rm.GRIPPER_ACTUATOR_NAME).ctrlrange[1] == pytest.approx(
        rm.GRIPPER_MAX_OPENING)
    np.testing.assert_allclose([m.jnt_actfrcrange[m.joint(n).id, 1] for n in rm.ARM_JOINT_NAMES],
                               rm.JOINT_EFFORT_LIMIT)
    np.testing.assert_allclose(plant.tcp_pose()[1], DOWN, atol=1e-9)
    assert m.opt.timestep == pytest.approx(0.002)


def test_starts_at_home_at_rest_with_gravity_compensated(plant, kin):
    assert isinstance(plant, Plant)
    plant.step(250)
    state = plant.state()
    # The cell puts the arm's base at the world origin: Pinocchio's TCP is the cell's TCP.
    position, rotation = plant.tcp_pose()
    np.testing.assert_allclose(position, kin.forward(np.array(state.q)).position, atol=1e-6)
    np.testing.assert_allclose(rotation, kin.forward(np.array(state.q)).rotation, atol=1e-6)
    assert state.t_ns == 250 * plant.timestep_ns
    np.testing.assert_allclose(state.q, HOME, atol=1e-6)
    np.testing.assert_allclose(state.qd, 0.0, atol=1e-6)
    # The motors carry the arm: shoulder and elbow torques are the arm's weight, not zero.
    assert abs(state.effort[1]) > 10.0 and abs(state.effort[2]) > 5.0
    np.testing.assert_allclose(state.wrench, 0.0, atol=0.05)  # empty tool, tared
    assert state.gripper == pytest.approx(rm.GRIPPER_MAX_OPENING, abs=1e-3)
    truth = plant.ground_truth()
    np.testing.assert_allclose(truth.peg_position, PEG_START, atol=1e-4)
    assert truth.insertion_depth == 0.0 and not truth.peg_grasped


def test_position_mode_tracks_a_step(plant):
    target = HOME + np.array([0.1, -0.1, 0.1, 0.1, -0.1, 0.1])
    plant.command_position(target)
    plant.step(250)
    assert plant.mode is ControlMode.POSITION
    np.testing.assert_allclose(plant.state().q, target, atol=1e-3)
    plant.step(250)
    np.testing.assert_allclose(plant.state().q, target, atol=1e-5)


def test_position_mode_follows_a_streamed_move_within_a_few_mrad(plant, kin):
    worst = move_to(plant, kin, above(HOLE, 0.15))
    assert worst < 5e-3
    reached = kin.forward(q_of(plant)).position
    np.testing.assert_allclose(reached, above(HOLE, 0.15), atol=2e-4)


def test_impedance_deflects_by_load_over_stiffness(plant):
    stiffness = np.array([400.0, 400.0, 300.0, 60.0, 60.0, 60.0])
    damping = np.array([60.0, 60.0, 30.0, 5.0, 5.0, 5.0])
    force = np.array([15.0, -10.0, -20.0])
    gripper = plant.model.body(rm.TOOL_BODY).id
    deflections = {}
    for mode in ("position", "impedance"):
        plant.reset()
        if mode == "impedance":
            plant.command_impedance(HOME, stiffness, damping)
        plant.data.xfrc_applied[gripper, :3] = force
        plant.step(750)
        deflections[mode] = q_of(plant) - HOME
    # Expected static deflection: tau = J^T F at the gripper's centre of mass (where
    # xfrc_applied acts), q = tau / K.
    jac = np.zeros((3, plant.model.nv))
    mujoco.mj_jacBodyCom(plant.model, plant.data, jac, None, gripper)
    torque = jac[:, :6].T @ force
    np.testing.assert_allclose(deflections["impedance"], torque / stiffness, rtol=0.05,
                               atol=2e-4)
    assert np.abs(deflections["position"]).max() < np.abs(deflections["impedance"]).max() / 20


def test_velocity_mode_tracks_velocity_and_hold_stops(plant):
    velocity = np.array([0.3, -0.2, 0.0, 0.1, 0.0, -0.5])
    plant.command_velocity(velocity)
    plant.step(150)
    assert plant.mode is ControlMode.VELOCITY
    np.testing.assert_allclose(plant.state().qd, velocity, atol=5e-3)
    plant.hold()
    held = q_of(plant)
    plant.step(250)
    np.testing.assert_allclose(plant.state().q, held, atol=2e-3)
    np.testing.assert_allclose(plant.state().qd, 0.0, atol=1e-4)


def test_streamed_commands_that_stop_leave_the_arm_on_the_last_one(plant):
    # The velocity feed-forward estimated from the stream must expire with the stream.
    for tick in range(1, 51):
        plant.command_position(HOME + 0.004 * tick * np.ones(6))
        plant.step(1)
    plant.step(250)
    np.testing.assert_allclose(plant.state().q, HOME + 0.2, atol=1e-4)


def test_bad_commands_raise_and_move_nothing(plant):
    before = plant.data.ctrl.copy(), plant.model.actuator_biasprm.copy()
    bad_calls = [
        (plant.command_position, (HOME[:5],), "needs 6 values"),
        (plant.command_position, (np.r_[HOME[:5], np.nan],), "outside"),
        (plant.command_position, (np.r_[HOME[:2], 3.5, HOME[3:]],), r"command\[2\]"),
        (plant.command_velocity, (np.full(6, 4.0),), "velocity command"),
        (plant.command_impedance, (HOME, -np.ones(6), np.ones(6)), "stiffness"),
        (plant.command_impedance, (HOME, np.full(6, 1e6), np.ones(6)), "stiffness"),
        (plant.command_impedance, (HOME, np.ones(6), np.full(6, np.inf)), "damping"),
        (plant.command_gripper, (0.2,), "gripper opening"),
        (plant.command_gripper, (float("nan"),), "gripper opening"),
        (plant.step, (-1,), "negative"),
        (plant.reset, (np.full(6, 9.0),), "reset q"),
    ]
    for call, args, match in bad_calls:
        with pytest.raises(ValueError, match=match):
            call(*args)
    np.testing.assert_array_equal(plant.data.ctrl, before[0])
    np.testing.assert_array_equal(plant.model.actuator_biasprm, before[1])


def test_a_physics_blow_up_is_reported_not_silently_reset(plant, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs the warning to ./MUJOCO_LOG.TXT
    plant.data.qvel[0] = 1e12
    with pytest.raises(PlantDiverged):
        plant.step(5)
    plant.reset()  # a reset clears it
    plant.step(5)


def test_gripper_opens_and_closes(plant):
    plant.command_gripper(0.04)
    plant.step(250)
    assert plant.state().gripper == pytest.approx(0.04, abs=1e-3)
    plant.command_gripper(0.0)
    plant.step(250)
    assert plant.state().gripper == pytest.approx(0.0, abs=1e-3)  # no part: fully closed


def test_reset_with_the_peg_in_the_gripper_holds_it_by_friction(plant):
    plant.reset(peg_in_gripper=True)
    assert plant.state().t_ns == 0
    tcp, rotation = plant.tcp_pose()
    grasp = tcp + rotation[:, 2] * rm.PEG_CENTRE_BELOW_TCP
    np.testing.assert_allclose(plant.ground_truth().peg_position, grasp, atol=1e-4)
    plant.step(500)
    truth = plant.ground_truth()
    assert truth.peg_grasped
    np.testing.assert_allclose(truth.peg_position, grasp, atol=3e-4)
    # The held peg's weight (60 g) shows on the tared sensor, along the tool axis.
    assert plant.state().wrench[2] == pytest.approx(0.06 * 9.81, abs=0.05)


def test_wrench_rises_when_the_peg_is_pushed_onto_the_fixture_top(plant, kin):
    plant.reset(peg_in_gripper=True)
    on_wall = HOLE[:2] + np.array([rm.HOLE_HALF_WIDTH + 0.0075, 0.0])  # peg centred on the +x wall
    peg_bottom_below_tcp = rm.PEG_CENTRE_BELOW_TCP + rm.PEG_HALF_EXTENTS[2]
    move_to(plant, kin, np.r_[on_wall, HOLE[2] + peg_bottom_below_tcp + 0.02])
    free = np.linalg.norm(plant.state().wrench[:3])
    descend_compliantly(plant, kin, on_wall, HOLE[2] + peg_bottom_below_tcp + 0.02,
                        HOLE[2] + peg_bottom_below_tcp - 0.01, dwell_s=0.5)
    state, truth = plant.state(), plant.ground_truth()
    assert free < 1.0
    assert np.linalg.norm(state.wrench[:3]) > 15.0
    # The fixture pushes the tool back up its own axis: negative along the sensor's z.
    assert state.wrench[2] < -10.0
    assert truth.insertion_depth == 0.0 and truth.peg_grasped


def test_pick_from_the_table_and_insert_into_the_hole(plant, kin):
    # Pick: tool down above the peg, open, descend, close on it, lift.
    move_to(plant, kin, above(PEG_START, 0.12))
    move_to(plant, kin, above(PEG_START, rm.PEG_CENTRE_BELOW_TCP))
    plant.command_gripper(0.0)
    plant.step(250)
    assert plant.ground_truth().peg_grasped
    move_to(plant, kin, above(PEG_START, 0.15))
    lifted = plant.ground_truth()
    assert lifted.peg_grasped and lifted.peg_position[2] > PEG_START[2] + 0.1
    # Transport above the hole, then insert in joint impedance mode, aiming 10 mm past the
    # hole's bottom so the arm keeps pressing.
    move_to(plant, kin, above(HOLE, 0.15))
    bottom_tcp = HOLE[2] - rm.HOLE_DEPTH + rm.PEG_CENTRE_BELOW_TCP + rm.PEG_HALF_EXTENTS[2]
    descend_compliantly(plant, kin, HOLE[:2], HOLE[2] + 0.15, bottom_tcp - 0.01)
    truth = plant.ground_truth()
    assert truth.insertion_depth >= 0.02, truth
    assert truth.peg_grasped
    assert plant.state().t_ns < 12_000_000_000


def test_arm_only_model_runs_without_a_cell():
    plant = MujocoPlant(dataclasses.replace(MujocoPlantConfig(), model_path=rm.ARM_MODEL))
    plant.command_position(HOME + 0.05)
    plant.step(250)
    np.testing.assert_allclose(plant.state().q, HOME + 0.05, atol=1e-3)
    truth = plant.ground_truth()
    assert truth.insertion_depth == 0.0 and not truth.peg_grasped
    with pytest.raises(ValueError, match="no peg"):
        plant.reset(peg_in_gripper=True)
