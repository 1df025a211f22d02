"""The reference policy speaking Cartesian: its joint-space path re-expressed as TCP moves.

With ``action_frame = "base_delta"`` each action is where the TCP should be relative to the pose
the policy observed: the displacement in base-frame axes (metres) and, with ``m+rad`` units,
the rotation vector from the observed orientation. That is how a policy trained on end-effector
deltas talks; the runtime maps it back to joint targets through IK (assurance/cartesian.py).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from peer.envelope import ActionFrame, ActionUnits
from stubs.robot_model.kinematics import arm_kinematics


class CartesianOutput:
    def __init__(self, units: str) -> None:
        self.kinematics = arm_kinematics()
        self.rotations = units == ActionUnits.METRES_RADIANS

    def __call__(self, q_obs: np.ndarray, joint_actions: np.ndarray) -> np.ndarray:
        """One row per action: TCP displacement (and rotation) from the pose at ``q_obs``."""
        anchor = self.kinematics.forward(q_obs)
        rows = []
        for q in joint_actions:
            pose = self.kinematics.forward(np.clip(q, self.kinematics.lower,
                                                   self.kinematics.upper))
            row = [*(pose.position - anchor.position)]
            if self.rotations:
                row += [*pin.log3(pose.rotation @ anchor.rotation.T)]
            rows.append(row)
        return np.array(rows)


def output_for(frame: str, units: str) -> CartesianOutput | None:
    """What turns the policy's joint path into the session's actions (None: joint actions)."""
    return CartesianOutput(units) if frame == ActionFrame.BASE_DELTA else None
