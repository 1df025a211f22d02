"""Pinocchio kinematics built from the MJCF arm: agreement with MuJoCo, Jacobian, IK, workspace."""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from assurance.kinematics import (
    ArmKinematics,
    IKConfig,
    JacobianFrame,
    KinematicsConfig,
    Pose,
    WorkspaceBox,
)
from stubs import robot_model as rm
from stubs.robot_model.kinematics import arm_kinematics

PROPERTY = settings(max_examples=40, deadline=None)


@pytest.fixture(scope="module")
def kin() -> ArmKinematics:
    return arm_kinematics()


@pytest.fixture(scope="module")
def mj_arm() -> tuple[mujoco.MjModel, mujoco.MjData]:
    model = mujoco.MjModel.from_xml_path(str(rm.ARM_MODEL))
    return model, mujoco.MjData(model)


def joint_vectors(kin: ArmKinematics) -> st.SearchStrategy[np.ndarray]:
    return st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6).map(
        lambda u: kin.lower + np.array(u) * (kin.upper - kin.lower))


def mujoco_tcp(mj_arm, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    model, data = mj_arm
    for name, value in zip(rm.ARM_JOINT_NAMES, q, strict=True):
        data.qpos[model.joint(name).qposadr[0]] = value
    mujoco.mj_kinematics(model, data)
    site = model.site(rm.TCP_SITE)
    return data.site_xpos[site.id].copy(), data.site_xmat[site.id].reshape(3, 3).copy()


def test_both_engines_load_the_same_arm(kin, mj_arm):
    model, _ = mj_arm
    full = pin.buildModelFromMJCF(str(rm.ARM_MODEL))
    mujoco_joints = [model.joint(j).name for j in range(model.njnt)]
    assert full.nq == model.nq == len(rm.ARM_JOINT_NAMES) + len(rm.GRIPPER_JOINT_NAMES)
    assert list(full.names[1:]) == mujoco_joints
    assert kin.dof == 6 and tuple(kin.model.names[1:]) == rm.ARM_JOINT_NAMES
    mj_ranges = np.array([model.joint(n).range for n in rm.ARM_JOINT_NAMES])
    np.testing.assert_allclose(kin.lower, mj_ranges[:, 0])
    np.testing.assert_allclose(kin.upper, mj_ranges[:, 1])
    assert kin.upper[2] == pytest.approx(np.pi) and kin.upper[0] == pytest.approx(2 * np.pi)


def test_zero_pose_matches_published_ur5e_kinematics(kin):
    # Flange at q = 0 from the DH table: x = a2 + a3, y = -(d4 + d6), z = d1 - d5. The TCP is
    # 0.165 m beyond the flange (37.5 mm sensor + 127.5 mm gripper), along -y at q = 0.
    flange = kin.model.frames[kin.model.getFrameId("flange")].placement  # on the wrist 3 joint
    tcp = kin.forward(np.zeros(6)).position
    np.testing.assert_allclose(tcp, [-0.8172, -0.2329 - 0.165, 0.0628], atol=1e-9)
    assert flange.translation[2] == pytest.approx(0.0996)


@PROPERTY
@given(data=st.data())
def test_tcp_agrees_with_mujoco_site(kin, mj_arm, data):
    q = data.draw(joint_vectors(kin))
    position, rotation = mujoco_tcp(mj_arm, q)
    pose = kin.forward(q)
    np.testing.assert_allclose(pose.position, position, atol=1e-6)
    np.testing.assert_allclose(pose.rotation, rotation, atol=1e-9)


@PROPERTY
@given(data=st.data())
def test_jacobian_matches_finite_differences(kin, data):
    q = data.draw(joint_vectors(kin)) * 0.98  # keep q ± eps inside the limits
    eps = 1e-7
    base = kin.forward(q)
    numeric = np.empty((6, 6))
    for j in range(6):
        moved = kin.forward(q + eps * np.eye(6)[j])
        numeric[:3, j] = (moved.position - base.position) / eps
        numeric[3:, j] = pin.log3(moved.rotation @ base.rotation.T) / eps
    jac = kin.jacobian(q)
    np.testing.assert_allclose(jac, numeric, atol=1e-5)
    pose, jac_again = kin.forward_with_jacobian(q)
    np.testing.assert_allclose(jac_again, jac)
    np.testing.assert_allclose(pose.position, base.position)
    rotate_back = np.kron(np.eye(2), base.rotation.T)
    np.testing.assert_allclose(kin.jacobian(q, JacobianFrame.TOOL), rotate_back @ jac, atol=1e-12)


@PROPERTY
@given(data=st.data())
def test_ik_never_leaves_joint_limits(kin, data):
    start = data.draw(joint_vectors(kin))
    position = np.array(data.draw(st.lists(st.floats(-1.2, 1.2), min_size=3, max_size=3)))
    rotvec = np.array(data.draw(st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3)))
    result = kin.solve(Pose(position, pin.exp3(rotvec)), start, IKConfig(max_iterations=30))
    assert kin.within_limits(result.q)
    assert 0 <= result.iterations <= 30
    if result.converged:
        np.testing.assert_allclose(kin.forward(result.q).position, position, atol=1e-5)


@PROPERTY
@given(data=st.data())
def test_reachable_target_converges_from_a_nearby_start(kin, data):
    goal = data.draw(joint_vectors(kin))
    # Reachable and not singular: near a singularity the pose is reachable but the nearby
    # start may legitimately converge to a different branch or slowly.
    assume(np.linalg.svd(kin.jacobian(goal), compute_uv=False)[-1] > 5e-3)
    offset = np.array(data.draw(st.lists(st.floats(-0.1, 0.1), min_size=6, max_size=6)))
    start = np.clip(goal + offset, kin.lower, kin.upper)
    target = kin.forward(goal)
    result = kin.solve(target, start)
    assert result.converged, result
    assert result.position_error <= 1e-6 and result.rotation_error <= 1e-5
    reached = kin.forward(result.q)
    np.testing.assert_allclose(reached.position, target.position, atol=1e-6)


def test_unreachable_target_reports_failure_inside_limits(kin):
    target = Pose(np.array([3.0, 0.0, 0.5]), np.eye(3))
    result = kin.solve(target, np.array(rm.HOME_Q), IKConfig(max_iterations=50))
    assert not result.converged
    assert result.iterations == 50
    assert result.position_error > 1.5
    assert result.residual >= result.position_error
    assert kin.within_limits(result.q)


def test_ik_rejects_bad_input(kin):
    target = kin.forward(np.array(rm.HOME_Q))
    with pytest.raises(ValueError, match="outside the joint limits"):
        kin.solve(target, np.array([7.0, 0, 0, 0, 0, 0]))
    with pytest.raises(ValueError, match="expected 6 joint values"):
        kin.solve(target, np.zeros(5))
    with pytest.raises(ValueError, match="not finite"):
        kin.solve(Pose(np.array([np.nan, 0, 0]), np.eye(3)), np.array(rm.HOME_Q))
    with pytest.raises(ValueError, match="orthonormal"):
        kin.solve(Pose(target.position, 2 * target.rotation), np.array(rm.HOME_Q))
    with pytest.raises(ValueError, match="not finite"):
        kin.forward(np.array([np.nan] * 6))
    with pytest.raises(ValueError):
        Pose(np.zeros(2), np.eye(3))
    with pytest.raises(ValueError, match="max_iterations"):
        IKConfig(max_iterations=0)
    with pytest.raises(ValueError, match="damping"):
        IKConfig(damping=-1.0)


def test_cartesian_delta_moves_the_tcp_by_the_delta(kin):
    q = np.array(rm.HOME_Q)
    before = kin.forward(q)
    down = kin.cartesian_delta_target(q, np.array([0.01, -0.02, -0.05]))
    assert down.converged
    after = kin.forward(down.q)
    np.testing.assert_allclose(after.position - before.position, [0.01, -0.02, -0.05], atol=1e-6)
    np.testing.assert_allclose(after.rotation, before.rotation, atol=1e-5)
    turn = kin.cartesian_delta_target(q, np.zeros(3), np.array([0.0, 0.0, 0.3]))
    assert turn.converged
    turned = kin.forward(turn.q)
    np.testing.assert_allclose(turned.rotation, pin.exp3(np.array([0, 0, 0.3])) @ before.rotation,
                               atol=1e-5)
    np.testing.assert_allclose(turned.position, before.position, atol=1e-6)
    with pytest.raises(ValueError, match="3-vectors"):
        kin.cartesian_delta_target(q, np.zeros(2))


def test_workspace_box():
    box = WorkspaceBox(np.array([-0.8, -0.5, 0.0]), np.array([-0.2, 0.5, 0.6]))
    assert box.contains(np.array([-0.5, 0.0, 0.3]))
    assert box.contains(np.array([-0.8, 0.5, 0.0]))  # the boundary is inside
    assert not box.contains(np.array([-0.5, 0.0, -0.001]))
    assert not box.contains(np.array([-0.1, 0.0, 0.3]))
    assert not box.contains(np.array([np.nan, 0.0, 0.3]))
    with pytest.raises(ValueError, match="3 values"):
        box.contains(np.array([-0.5, 0.0]))
    with pytest.raises(ValueError, match="exceeds"):
        WorkspaceBox(np.array([0.0, 0.0, 1.0]), np.array([1.0, 1.0, 0.0]))
    with pytest.raises(ValueError, match="finite"):
        WorkspaceBox(np.array([0.0, 0.0, -np.inf]), np.array([1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="3-vectors"):
        WorkspaceBox(np.zeros(2), np.ones(2))


def test_unknown_frame_or_joint_is_a_clear_error():
    model = pin.buildModelFromMJCF(str(rm.ARM_MODEL))
    with pytest.raises(ValueError, match="no frame"):
        ArmKinematics(KinematicsConfig(model, "nope", rm.ARM_JOINT_NAMES))
    with pytest.raises(ValueError, match="no joints"):
        ArmKinematics(KinematicsConfig(model, rm.TCP_SITE, ("shoulder_pan_joint", "nope")))
