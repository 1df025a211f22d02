"""Cartesian proposals: TCP displacements turned into joint targets before admission decides.

A session whose ``action_frame`` is ``base_delta`` proposes, per action, where the TCP should
be relative to where it was when the policy observed the robot: a translation in base-frame
axes (metres), and with ``action_units = "m+rad"`` also a rotation vector (axis·angle, radians)
applied on the left of the observed orientation; without it the observed orientation is held.
A robot with a gripper column appends the gripper command as the last value of each action.

The anchor is the joint state the policy saw (the chunk's state fingerprint), or the measured
state when the chunk carries none. Every action must put the TCP inside the workspace box and
have an IK solution (warm-started from the previous action's, so consecutive targets stay on
one branch); otherwise the whole chunk is ``INFEASIBLE``, with the action and the cause in the
decision's detail. The joint targets then pass the same divergence and feasibility gates, and
the same joint-space projection, as a joint-space chunk.

Pure: no I/O, threads or clocks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from assurance.kinematics import ArmKinematics, IKConfig, Pose, WorkspaceBox
from assurance.limits import JointLimits

BASE_DELTA = "base_delta"
"""The Cartesian action frame: TCP displacements from the observed pose, base-frame axes."""
TRANSLATION_UNITS = "m"
POSE_UNITS = "m+rad"
CARTESIAN_UNITS = (TRANSLATION_UNITS, POSE_UNITS)

MAPPING_IK = IKConfig(max_iterations=30, position_tolerance=1e-5, rotation_tolerance=1e-4)
"""Tolerances for proposals: ten micrometres is far below any policy's noise, and a solve
that needs more than 30 damped steps from the previous action's solution is no small step."""


def action_width(units: str, gripper: bool) -> int:
    """Values per Cartesian action for the given units, plus the gripper column if any."""
    return (3 if units == TRANSLATION_UNITS else 6) + int(gripper)


@dataclass(frozen=True, slots=True, eq=False)
class Mapped:
    """Joint targets for every action, or why there are none."""

    joints: np.ndarray | None
    detail: str = ""


class CartesianMapper:
    """Turns Cartesian chunks into joint-space actions for one robot (see the module doc)."""

    def __init__(self, kinematics: ArmKinematics, limits: JointLimits, units: str,
                 workspace: WorkspaceBox | None = None, ik: IKConfig = MAPPING_IK) -> None:
        if units not in CARTESIAN_UNITS:
            raise ValueError(f"Cartesian units must be one of {CARTESIAN_UNITS}, got {units!r}")
        arm = int(limits.arm_mask.sum())
        if arm != kinematics.dof:
            raise ValueError(f"the robot has {arm} arm joints, its kinematic model has "
                             f"{kinematics.dof}")
        self.kinematics, self.limits, self.units = kinematics, limits, units
        self.workspace, self.ik = workspace, ik
        self.width = action_width(units, limits.gripper_index is not None)

    def to_joints(self, actions: np.ndarray, anchor_q: np.ndarray) -> Mapped:
        """Joint targets (one row per action, the robot's full width) from ``anchor_q``.

        ``actions`` must be finite and ``width`` wide (the content gates say so first).
        """
        arm = self.limits.arm_mask
        seed = np.clip(np.asarray(anchor_q, dtype=float)[arm], self.kinematics.lower,
                       self.kinematics.upper)
        anchor = self.kinematics.forward(seed)
        targets = [self._target(anchor, action) for action in actions]
        for row, target in enumerate(targets):
            # Finite but huge actions overflow into a pose that is not one (exp3 of 1e200 rad
            # is NaN): no IK solution, said as such, never an error out of admission.
            if not (np.isfinite(target.position).all() and np.isfinite(target.rotation).all()):
                return Mapped(None, f"action {row}: the TCP target is not a finite pose")
        if self.workspace is not None:
            for row, target in enumerate(targets):
                if not self.workspace.contains(target.position):
                    return Mapped(None, f"action {row}: TCP {_mm(target.position)} is outside "
                                        "the workspace box")
        solutions, failure = self.kinematics.follow(targets, seed, self.ik)
        if failure is not None:
            row = solutions.shape[0]
            return Mapped(None, f"action {row}: no IK solution for TCP "
                                f"{_mm(targets[row].position)} (off by {failure.residual:.1e})")
        joints = np.empty((actions.shape[0], self.limits.dim))
        joints[:, arm] = solutions
        if self.limits.gripper_index is not None:
            joints[:, self.limits.gripper_index] = actions[:, -1]
        joints.setflags(write=False)
        return Mapped(joints)

    def _target(self, anchor: Pose, action: np.ndarray) -> Pose:
        position = anchor.position + action[:3]
        if self.units == TRANSLATION_UNITS:
            return Pose(position, anchor.rotation)
        return Pose(position, pin.exp3(np.asarray(action[3:6], dtype=float)) @ anchor.rotation)


def _mm(position: np.ndarray) -> str:
    return "[" + ", ".join(f"{1000.0 * v:.1f}" for v in position) + "] mm"
