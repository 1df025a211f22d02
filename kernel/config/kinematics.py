"""The robot's kinematic model and workspace (the ``robot`` keys that name them).

``robot.kinematics`` names a model that ships with warden (``"ur5e"``); ``robot.model`` names a
model file (MJCF ``.xml`` or URDF ``.urdf``) relative to the file that names it, with
``robot.tcp_frame`` and optionally ``robot.joints`` (see :mod:`kernel.robot_model`). A journal
also carries ``robot.model_sha256``: the replay refuses a model file that changed since the run.
``robot.workspace`` is an axis-aligned box ``{lower: [x, y, z], upper: [x, y, z]}`` in metres,
base frame, that every proposed TCP position must lie in (Cartesian sessions).

The model is optional for a joint-space session (without it the contact owner can only hold
compliantly); a Cartesian (``base_delta``) session needs it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from assurance.cartesian import BASE_DELTA, CARTESIAN_UNITS, CartesianMapper, action_width
from assurance.kinematics import ArmKinematics, WorkspaceBox
from assurance.limits import JointLimits
from kernel.config.workspace import workspace_box
from kernel.core.config import ClientSide
from kernel.model_file import BUILTIN, model_spec
from kernel.robot_model import ModelError, load_kinematics
from kernel.scenario.fields import Where, mapping, text


def robot_kinematics(
    robot: Mapping[str, Any], where: Where, limits: JointLimits
) -> ArmKinematics | None:
    """The arm's kinematics, if the robot section names a model."""
    spec = model_spec(robot, where)
    if spec is None:
        return None
    try:
        # One read: the digest compared is that of the very bytes parsed.
        kinematics = load_kinematics(spec, int(limits.arm_mask.sum()))
        changed = robot.get("model_sha256") is not None and kinematics.config.sha256 != text(
            robot, "model_sha256", where)
    except ModelError as error:
        raise where.at("model" if "model" in robot else "kinematics").error(str(error)) from None
    if changed:
        raise where.at("model_sha256").error(
            f"{spec.path} changed since this was recorded (its SHA-256 differs)")
    return kinematics


def cartesian_mapper(
    doc: Mapping[str, Any], where: Where, limits: JointLimits, client: ClientSide,
    kinematics: ArmKinematics | None,
) -> CartesianMapper | None:
    """The mapper a Cartesian session needs, None for a joint-space one."""
    robot = mapping(doc, "robot", where)
    here = where.at("robot")
    workspace = _workspace(robot, here)
    if client.action_frame != BASE_DELTA:
        return None
    session = where.at("session")
    if kinematics is None:
        raise here.error(f"needs 'kinematics' (one of {', '.join(BUILTIN)}) or 'model' when "
                         f"session.action_frame is {BASE_DELTA!r}")
    if client.action_units not in CARTESIAN_UNITS:
        raise session.at("action_units").error(
            f"must be one of {', '.join(CARTESIAN_UNITS)} with action_frame {BASE_DELTA!r}, "
            f"got {client.action_units!r}")
    width = action_width(client.action_units, limits.gripper_index is not None)
    if client.action_dim != width:
        raise session.at("action_dim").error(
            f"must be {width} for {client.action_units!r} actions on this robot, "
            f"got {client.action_dim}")
    try:
        return CartesianMapper(kinematics, limits, client.action_units, workspace)
    except ValueError as error:
        raise here.error(str(error)) from None


def _workspace(robot: Mapping[str, Any], where: Where) -> WorkspaceBox | None:
    if robot.get("workspace") is None:
        return None
    box = mapping(robot, "workspace", where)
    return workspace_box(box.get("lower"), box.get("upper"), where.at("workspace"),
                         ("lower", "upper"))
