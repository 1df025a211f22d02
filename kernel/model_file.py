"""Which robot model file ``[robot]`` names: read by warden's loader and the safety monitor alike.

``robot.kinematics`` names a model that ships with warden (``"ur5e"``); ``robot.model`` names a
model file, relative to the file that names it, with ``robot.tcp_frame`` and optionally
``robot.joints``. Only the file is located here (nothing is parsed): warden's loader reads it
with Pinocchio (:mod:`kernel.robot_model`), the safety monitor's space check with MuJoCo
(:mod:`kernel.safety.space`), and neither imports the other's.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import msgspec

from kernel.scenario.fields import Where, text

MODELS_DIR = Path(__file__).resolve().parents[1] / "manifests" / "models"


class ModelSpec(msgspec.Struct, frozen=True):
    path: Path
    tcp_frame: str
    """The TCP: a site (MJCF) or a frame of the model; its body and those below are the tool."""
    joints: tuple[str, ...] | None = None
    """The arm's joints, base to tool; None: the model's first ``dof`` joints."""


BUILTIN: dict[str, ModelSpec] = {
    "ur5e": ModelSpec(MODELS_DIR / "ur5e.xml", "tcp", (
        "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
        "wrist_2_joint", "wrist_3_joint")),
}


def model_spec(robot: Mapping[str, Any], where: Where) -> ModelSpec | None:
    """The model ``robot`` names, or None when it names none.

    Raises:
        ScenarioError: both keys, an unknown built-in name, a key that needs ``model``
            without it, or joints that are not a list of names (naming the key).
    """
    if robot.get("kinematics") is not None and robot.get("model") is not None:
        raise where.at("model").error("name either 'kinematics' (a built-in model) or 'model' "
                                      "(a file), not both")
    if robot.get("kinematics") is not None:
        name = text(robot, "kinematics", where)
        if name not in BUILTIN:
            raise where.at("kinematics").error(
                f"unknown model {name!r} (expected one of {', '.join(BUILTIN)})")
        return BUILTIN[name]
    if robot.get("model") is None:
        for key in ("tcp_frame", "joints", "model_sha256"):
            if key in robot:
                raise where.at(key).error("needs 'model' (the robot model file)")
        return None
    path = Path(text(robot, "model", where))
    if not path.is_absolute():
        path = Path(where.file).resolve().parent / path
    joints = robot.get("joints")
    if joints is not None and not (isinstance(joints, list) and joints
                                   and all(isinstance(j, str) and j for j in joints)):
        raise where.at("joints").error("must be a list of joint names")
    return ModelSpec(path, text(robot, "tcp_frame", where),
                     tuple(joints) if joints is not None else None)
