"""Classical moves for transport, pick and retreat: plan once, play back while in charge.

A move's clock advances only on ticks where the planner actually owns motion, so a fallback
hold in the middle of a move pauses it instead of letting it run ahead of the arm.
"""

from __future__ import annotations

import numpy as np

from assurance.kinematics import ArmKinematics, Pose
from skills.trajectory import JointSample, JointTrajectory, MotionLimits, plan_joint_move


class PlanningError(RuntimeError):
    """No joint solution or no trajectory for a requested classical move."""


class PlannedMove:
    def __init__(self, trajectory: JointTrajectory) -> None:
        self.trajectory = trajectory
        self.elapsed_s = 0.0
        self.target: np.ndarray = trajectory.sample(trajectory.duration).position
        """Where the move ends (sampled once: it is read every tick while the move settles)."""

    def advance(self, dt_s: float) -> JointSample:
        self.elapsed_s += dt_s
        return self.trajectory.sample(self.elapsed_s)

    @property
    def finished(self) -> bool:
        return self.elapsed_s >= self.trajectory.duration


class Planner:
    def __init__(self, kinematics: ArmKinematics, limits: MotionLimits,
                 tool_down: np.ndarray) -> None:
        self.kin = kinematics
        self.limits = limits
        self.tool_down = tool_down

    def to_joints(self, q_from: np.ndarray, q_to: np.ndarray) -> PlannedMove:
        move = plan_joint_move(np.asarray(q_from, float), np.asarray(q_to, float), self.limits)
        if not move.within(self.limits):
            raise PlanningError("planned move leaves the joint limits")
        return PlannedMove(move)

    def to_tool_pose(self, q_from: np.ndarray, tcp: np.ndarray) -> PlannedMove:
        """A joint-space move that ends with the tool down at ``tcp``."""
        return self.to_joints(q_from, self.solve(q_from, tcp))

    def solve(self, q_seed: np.ndarray, tcp: np.ndarray) -> np.ndarray:
        result = self.kin.solve(Pose(np.asarray(tcp, float), self.tool_down), q_seed)
        if not result.converged:
            raise PlanningError(f"no IK solution for TCP {np.round(tcp, 4).tolist()} "
                                f"(residual {result.residual:.2e})")
        return result.q
