"""The cell as the clearance check sees it: the arm's collision geoms, the tool, the held part
and the world's solids in one Pinocchio ``GeometryModel``, with the constants of the model that
bound how far each geom can travel when a joint turns (:mod:`assurance.collision` uses them).

Pure: no I/O, no clock.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np
import pinocchio as pin

from assurance.solids import (
    SolidSpec,
    bounding_radius,
    coal_shape,
    joint_axis,
    joint_reach,
    placement,
)


class RobotSolid(StrEnum):
    LINK = "link"
    TOOL = "tool"
    PART = "part"


@dataclass(frozen=True, slots=True, eq=False)
class CellGeometry:
    model: pin.GeometryModel
    roles: tuple[RobotSolid | SolidSpec, ...]
    """Per geom: what it is on the robot, or the world's solid it is."""
    joints: tuple[int, ...]
    radii: np.ndarray
    """(geoms, dof): how far a point of geom g can be from joint j's origin (0: not moved by j)."""
    joint_of_q: np.ndarray
    """Per configuration coordinate, the joint it belongs to."""
    axes: tuple[np.ndarray | None, ...]
    """Per configuration coordinate, its joint's axis in the joint's frame (None: prismatic)."""
    rho: np.ndarray
    """Per geom, its bounding radius about its placement's origin."""
    axis_array: np.ndarray
    """(dof, 3): the axes, a prismatic joint's as zeros."""
    prismatic: np.ndarray
    """Per configuration coordinate, whether its joint is prismatic."""
    joint_list: tuple[int, ...]
    """Per configuration coordinate, its joint (``joint_of_q`` as ints)."""
    parent_column: np.ndarray
    """Per geom, the configuration coordinate of the joint it is fixed to (-1: the base)."""
    local_centres: np.ndarray
    """(geoms, 3): each geom's centre in its joint's frame (the world's, on the base)."""


def with_part(model: pin.Model, arm: pin.GeometryModel, part: SolidSpec | None,
              solids: tuple[SolidSpec, ...], tcp: int, held: bool) -> CellGeometry:
    """The arm's geoms, the part on the TCP when ``held``, and the world's ``solids``."""
    geometry = arm.copy()
    roles: list[RobotSolid | SolidSpec] = [role(model, g, tcp) for g in arm.geometryObjects]
    if held and part is not None:
        frame = model.frames[tcp]
        geometry.addGeometryObject(pin.GeometryObject(
            "part", frame.parentJoint, tcp, frame.placement * placement(part), coal_shape(part)))
        roles.append(RobotSolid.PART)
    for solid in solids:
        geometry.addGeometryObject(pin.GeometryObject(
            solid.name, 0, 0, placement(solid), coal_shape(solid)))
        roles.append(solid)
    joints = tuple(int(g.parentJoint) for g in geometry.geometryObjects)
    joint_of_q = np.zeros(model.nq, dtype=int)
    for joint in range(1, model.njoints):
        joint_of_q[model.joints[joint].idx_q] = joint
    axes = tuple(joint_axis(model.joints[joint]) for joint in joint_of_q.tolist())
    rho = np.array([bounding_radius(g.geometry) for g in geometry.geometryObjects])
    prismatic = np.array([axis is None for axis in axes])
    axis_array = np.array([np.zeros(3) if axis is None else axis for axis in axes])
    column = {joint: q for q, joint in reversed(list(enumerate(joint_of_q.tolist())))}
    parent_column = np.array([column.get(joint, -1) for joint in joints])
    local_centres = np.array([g.placement.translation for g in geometry.geometryObjects])
    return CellGeometry(geometry, tuple(roles), joints, joint_reach(model, geometry), joint_of_q,
                        axes, rho, axis_array, prismatic, tuple(joint_of_q.tolist()),
                        parent_column, local_centres)


def role(model: pin.Model, geom: pin.GeometryObject, tcp_frame: int) -> RobotSolid:
    """A geom on the TCP's joint that hangs off another body than that joint's own link (the
    gripper and its fingers) is the tool; every other robot geom is a link."""
    joint = model.frames[tcp_frame].parentJoint
    if geom.parentJoint != joint:
        return RobotSolid.LINK
    link = next(i for i, f in enumerate(model.frames)
                if f.parentJoint == joint and f.type == pin.FrameType.BODY)
    return RobotSolid.LINK if geom.parentFrame == link else RobotSolid.TOOL


def reach_about_axes(geometry: CellGeometry, geoms: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """(configurations, len(geoms), dof): how far each of ``geoms`` reaches from each joint's
    axis (its centre's distance from the axis plus its bounding radius; 1 per metre for a
    prismatic joint), where the joint moves it (else 0). ``joints``: (configurations, dof, 4,
    4), each joint's placement in the world."""
    rotations, origins = joints[:, :, :3, :3], joints[:, :, :3, 3]
    axes = np.einsum("rjab,jb->rja", rotations, geometry.axis_array)
    column = geometry.parent_column[geoms]
    carried = np.einsum("rgab,gb->rga", rotations[:, column], geometry.local_centres[geoms])
    centres = np.where((column >= 0)[None, :, None], carried + origins[:, column],
                       geometry.local_centres[geoms][None])
    arm = centres[:, :, None, :] - origins[:, None, :, :]  # (r, geoms, dof, 3)
    radius = np.linalg.norm(np.cross(axes[:, None, :, :], arm), axis=-1)
    radius[..., geometry.prismatic] = 1.0
    radii = geometry.radii[geoms]
    return np.where(radii[None] > 0.0, radius + geometry.rho[geoms, None][None], 0.0)


__all__ = ["CellGeometry", "RobotSolid", "reach_about_axes", "with_part"]
