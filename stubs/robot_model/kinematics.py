"""The simulated arm's kinematics, for stand-ins that need them (the reference policy's
Cartesian output, plant tests): built from the same model file the manifests name."""

from __future__ import annotations

import pinocchio as pin

from assurance.kinematics import ArmKinematics, KinematicsConfig
from stubs.robot_model import ARM_JOINT_NAMES, ARM_MODEL, TCP_SITE


def arm_kinematics() -> ArmKinematics:
    model = pin.buildModelFromMJCF(str(ARM_MODEL))
    return ArmKinematics(KinematicsConfig(model, TCP_SITE, ARM_JOINT_NAMES, str(ARM_MODEL)))
