"""Classical moves for transport, pick and retreat: plan once, play back while in charge.

A move's clock advances only on ticks where the planner actually owns motion, so a fallback
hold in the middle of a move pauses it instead of letting it run ahead of the arm.
"""

from __future__ import annotations

from enum import StrEnum

import numpy as np

from assurance.kinematics import ArmKinematics, Pose
from skills.trajectory import JointSample, JointTrajectory, MotionLimits, plan_joint_move


class PlanningError(RuntimeError):
    """No joint solution or no trajectory for a requested classical move."""


class MoveStatus(StrEnum):
    """Where a requested classical move stands (the core reports it to the task)."""

    NONE = "none"
    WAITING = "waiting"
    """Requested; starts once the planner owns the tick and the arm has settled."""
    PLAYING = "playing"
    FINISHED = "finished"
    REFUSED = "refused"
    """No rest-to-rest move inside the limits reaches the target."""


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


def joint_move(q_from: np.ndarray, q_to: np.ndarray, limits: MotionLimits) -> PlannedMove:
    """A time-optimal rest-to-rest joint move that stays inside the position limits.

    Raises:
        PlanningError: the move would leave the joint limits.
        ValueError: a vector has the wrong length, is not finite or is outside the limits.
    """
    move = plan_joint_move(np.asarray(q_from, float), np.asarray(q_to, float), limits)
    if not move.within(limits):
        raise PlanningError("planned move leaves the joint limits")
    return PlannedMove(move)


class Planner:
    def __init__(self, kinematics: ArmKinematics, limits: MotionLimits,
                 tool_down: np.ndarray) -> None:
        self.kin = kinematics
        self.limits = limits
        self.tool_down = tool_down

    def to_joints(self, q_from: np.ndarray, q_to: np.ndarray) -> PlannedMove:
        return joint_move(q_from, q_to, self.limits)

    def to_tool_pose(self, q_from: np.ndarray, tcp: np.ndarray) -> PlannedMove:
        """A joint-space move that ends with the tool down at ``tcp``."""
        return self.to_joints(q_from, self.solve(q_from, tcp))

    def solve(self, q_seed: np.ndarray, tcp: np.ndarray) -> np.ndarray:
        result = self.kin.solve(Pose(np.asarray(tcp, float), self.tool_down), q_seed)
        if not result.converged:
            raise PlanningError(f"no IK solution for TCP {np.round(tcp, 4).tolist()} "
                                f"(residual {result.residual:.2e})")
        return result.q
