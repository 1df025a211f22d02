"""The robot's kinematic model and workspace, for sessions that propose Cartesian actions.

``robot.kinematics`` names a built-in arm model (``"ur5e"``, the MJCF the simulated cell runs);
``robot.workspace`` is an axis-aligned box ``{lower: [x, y, z], upper: [x, y, z]}`` in metres,
base frame, that every proposed TCP position must lie in. Both matter only to a session whose
``action_frame`` is ``base_delta``, and such a session needs the model.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from assurance.cartesian import BASE_DELTA, CARTESIAN_UNITS, CartesianMapper, action_width
from assurance.kinematics import ArmKinematics, KinematicsConfig, WorkspaceBox
from assurance.limits import JointLimits
from kernel.core.config import ClientSide
from kernel.scenario.fields import Where, mapping, text, vector

MODELS: dict[str, KinematicsConfig] = {"ur5e": KinematicsConfig()}


def cartesian_mapper(
    doc: Mapping[str, Any], where: Where, limits: JointLimits, client: ClientSide
) -> CartesianMapper | None:
    """The mapper a Cartesian session needs, None for a joint-space one."""
    robot = mapping(doc, "robot", where)
    here = where.at("robot")
    model = _model(robot, here)
    workspace = _workspace(robot, here)
    if client.action_frame != BASE_DELTA:
        return None
    session = where.at("session")
    if model is None:
        raise here.error(f"needs 'kinematics' (one of {', '.join(MODELS)}) when "
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
        return CartesianMapper(ArmKinematics(model), limits, client.action_units, workspace)
    except ValueError as error:
        raise here.error(str(error)) from None


def _model(robot: Mapping[str, Any], where: Where) -> KinematicsConfig | None:
    if robot.get("kinematics") is None:
        return None
    name = text(robot, "kinematics", where)
    if name not in MODELS:
        raise where.at("kinematics").error(
            f"unknown model {name!r} (expected one of {', '.join(MODELS)})")
    return MODELS[name]


def _workspace(robot: Mapping[str, Any], where: Where) -> WorkspaceBox | None:
    if robot.get("workspace") is None:
        return None
    box = mapping(robot, "workspace", where)
    here = where.at("workspace")
    lower = vector(box.get("lower"), here.at("lower"), 3)
    upper = vector(box.get("upper"), here.at("upper"), 3)
    for axis, (low, high) in enumerate(zip(lower, upper, strict=True)):
        if low > high:
            raise here.at("lower").at(axis).error(f"{low} exceeds the upper bound {high}")
    return WorkspaceBox(lower, upper)
