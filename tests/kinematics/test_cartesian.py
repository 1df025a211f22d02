"""Cartesian proposals mapped to joint targets: exact where reachable, refused where not."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from assurance.cartesian import MAPPING_IK, CartesianMapper
from assurance.kinematics import ArmKinematics, Pose, WorkspaceBox
from assurance.limits import JointLimits
from stubs.policy_server.cartesian import CartesianOutput
from stubs.robot_model.kinematics import arm_kinematics

Q0 = np.array([0.0, -1.2, 1.5, -1.87, -1.57, 0.0])
ARM = JointLimits(np.full(6, -6.28), np.full(6, 6.28), np.full(6, 3.14), np.full(6, 40.0))
WITH_GRIPPER = JointLimits(np.r_[np.full(6, -6.28), 0.0], np.r_[np.full(6, 6.28), 0.085],
                           np.r_[np.full(6, 3.14), np.inf], np.r_[np.full(6, 40.0), np.inf],
                           gripper_index=6)


@pytest.fixture(scope="module")
def kin() -> ArmKinematics:
    return arm_kinematics()


def _descent(count: int, step: float = 0.001) -> np.ndarray:
    return np.array([[0.0002 * k, -0.0001 * k, -step * k] for k in range(1, count + 1)])


def test_translations_reach_their_targets_with_the_orientation_held(kin: ArmKinematics) -> None:
    mapped = CartesianMapper(kin, ARM, "m").to_joints(_descent(20), Q0)
    assert mapped.joints is not None and mapped.joints.shape == (20, 6)
    anchor = kin.forward(Q0)
    for delta, q in zip(_descent(20), mapped.joints, strict=True):
        pose = kin.forward(q)
        assert np.linalg.norm(pose.position - (anchor.position + delta)) <= 2e-5
        assert np.linalg.norm(pin.log3(pose.rotation @ anchor.rotation.T)) <= 2e-4
    assert not mapped.joints.flags.writeable


def test_rotations_are_applied_in_base_axes(kin: ArmKinematics) -> None:
    actions = np.array([[0.0, 0.0, -0.001 * k, 0.0, 0.0, 0.01 * k] for k in range(1, 6)])
    mapped = CartesianMapper(kin, ARM, "m+rad").to_joints(actions, Q0)
    assert mapped.joints is not None
    anchor = kin.forward(Q0)
    final = kin.forward(mapped.joints[-1])
    wanted = pin.exp3(np.array([0.0, 0.0, 0.05])) @ anchor.rotation
    assert np.linalg.norm(pin.log3(final.rotation @ wanted.T)) <= 2e-4


def test_the_gripper_column_passes_through(kin: ArmKinematics) -> None:
    actions = np.c_[_descent(4), [0.08, 0.08, 0.0, 0.0]]
    anchor = np.r_[Q0, 0.08]
    mapped = CartesianMapper(kin, WITH_GRIPPER, "m").to_joints(actions, anchor)
    assert mapped.joints is not None and mapped.joints.shape == (4, 7)
    assert mapped.joints[:, 6].tolist() == [0.08, 0.08, 0.0, 0.0]


def test_leaving_the_workspace_refuses_the_chunk_and_names_the_action(
        kin: ArmKinematics) -> None:
    tcp = kin.forward(Q0).position
    box = WorkspaceBox(tcp - 0.0025, tcp + 0.0025)
    mapped = CartesianMapper(kin, ARM, "m", box).to_joints(_descent(5), Q0)
    assert mapped.joints is None and "action 2" in mapped.detail and "workspace" in mapped.detail


def test_an_unreachable_target_has_no_solution(kin: ArmKinematics) -> None:
    actions = np.array([[0.0, 0.0, -0.001], [1.5, 0.0, 0.0]])
    mapped = CartesianMapper(kin, ARM, "m").to_joints(actions, Q0)
    assert mapped.joints is None and "action 1: no IK solution" in mapped.detail


def test_a_finite_rotation_that_overflows_the_pose_has_no_solution(kin: ArmKinematics) -> None:
    actions = np.array([[0.0, 0.0, -0.001, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1e200, 0.0, 0.0]])
    mapped = CartesianMapper(kin, ARM, "m+rad").to_joints(actions, Q0)
    assert mapped.joints is None and "action 1: the TCP target is not a finite pose" in (
        mapped.detail)


def test_the_mapper_refuses_a_robot_the_model_does_not_describe(kin: ArmKinematics) -> None:
    five = JointLimits(np.full(5, -1.0), np.full(5, 1.0), np.full(5, 1.0), np.full(5, 1.0))
    with pytest.raises(ValueError, match="5 arm joints"):
        CartesianMapper(kin, five, "m")
    with pytest.raises(ValueError, match="units"):
        CartesianMapper(kin, ARM, "mm")


@settings(max_examples=25, deadline=None)
@given(direction=st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3),
       speed=st.floats(0.0005, 0.004))
def test_small_paths_map_inside_the_limits_and_onto_the_targets(
        direction: list[float], speed: float) -> None:
    kin = arm_kinematics()
    unit = np.array(direction) / max(np.linalg.norm(direction), 1e-9)
    actions = np.array([unit * speed * k for k in range(1, 11)])
    mapped = CartesianMapper(kin, ARM, "m").to_joints(actions, Q0)
    assert mapped.joints is not None
    assert kin.within_limits(mapped.joints[-1])
    reached = kin.forward(mapped.joints[-1]).position
    assert np.linalg.norm(reached - (kin.forward(Q0).position + actions[-1])) <= 2e-5


def test_the_reference_policy_output_maps_back_to_its_joint_path(kin: ArmKinematics) -> None:
    """The server's Cartesian view of a joint path, mapped by the runtime, lands on the path's
    TCP positions (the orientation is the anchor's, so joints may differ slightly)."""
    path = Q0 + np.outer(np.arange(1, 11), [0.0, 0.002, 0.004, -0.006, 0.0, 0.0])
    deltas = CartesianOutput("m")(Q0, path)
    mapped = CartesianMapper(kin, ARM, "m", ik=MAPPING_IK).to_joints(deltas, Q0)
    assert mapped.joints is not None
    for q_path, q_mapped in zip(path, mapped.joints, strict=True):
        gap = kin.forward(q_path).position - kin.forward(q_mapped).position
        assert np.linalg.norm(gap) <= 2e-5


def test_follow_reports_the_first_failure(kin: ArmKinematics) -> None:
    anchor = kin.forward(Q0)
    targets = [Pose(anchor.position + np.array([0.0, 0.0, -0.001]), anchor.rotation),
               Pose(anchor.position + np.array([3.0, 0.0, 0.0]), anchor.rotation)]
    solutions, failure = kin.follow(targets, Q0, MAPPING_IK)
    assert solutions.shape == (1, 6) and failure is not None and not failure.converged
