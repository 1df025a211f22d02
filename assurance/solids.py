"""The solids of a cell as coal shapes, and what the clearance check needs to know of them.

A :class:`SolidSpec` is one primitive solid as the manifest writes it (MuJoCo's sizes: half
extents; a radius and a half length); here it becomes a coal shape and a placement, and the
arm's collision geoms are put on the arm's reduced model. :func:`joint_reach` bounds how far a
geom can be from each joint (:mod:`assurance.collision` uses it for the motion between two
configurations). Pure: no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import coal
import numpy as np
import pinocchio as pin

from assurance.kinematics import ArmKinematics


class Shape(StrEnum):
    BOX = "box"
    SPHERE = "sphere"
    CYLINDER = "cylinder"
    CAPSULE = "capsule"


@dataclass(frozen=True, slots=True)
class SolidSpec:
    """A primitive solid: MuJoCo-style sizes (half extents; radius and half length)."""

    name: str
    shape: Shape
    size: tuple[float, ...]
    position: tuple[float, float, float]
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Roll, pitch, yaw about the fixed x, y, z axes (radians)."""
    allow_contact: frozenset[str] = frozenset()
    """Phases in which the tool and the held part may touch it (obstacles only)."""
    keep_out: bool = False


def arm_geometry(kinematics: ArmKinematics) -> pin.GeometryModel:
    """The model's collision geoms on the arm's model (the other joints locked as
    :class:`ArmKinematics` locks them)."""
    config = kinematics.config
    if config.collision is None or not config.collision.geometryObjects:
        raise ValueError(f"{config.source} has no collision geoms (primitive geoms of an MJCF "
                         "model): [geometry] needs them")
    full = config.model
    locked = [full.getJointId(full.names[j]) for j in range(1, full.njoints)
              if full.names[j] not in config.arm_joints]
    if not locked:
        return config.collision.copy()
    _, geometries = pin.buildReducedModel(full, [config.collision], locked, pin.neutral(full))
    return geometries[0]


def joint_axis(joint: pin.JointModel) -> np.ndarray | None:
    """A revolute joint's axis in its own frame; None for a prismatic one.

    Raises:
        ValueError: a joint of another kind (the arm's joints are 1-DoF)."""
    name = joint.shortname()
    fixed = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0),
             "JointModelRZ": (0.0, 0.0, 1.0)}
    if name in fixed:
        return np.array(fixed[name])
    if name == "JointModelRevoluteUnaligned":
        return np.array(joint.axis, dtype=float)
    if name.startswith("JointModelP"):
        return None
    raise ValueError(f"joint of kind {name} is not a 1-DoF revolute or prismatic joint")


def joint_reach(model: pin.Model, geometry: pin.GeometryModel) -> np.ndarray:
    """R[g, j]: a bound on the distance of any point of geom g from the origin of the arm's
    joint j, for the joints that move g (the chain's lengths: configuration-independent)."""
    radii = np.zeros((len(geometry.geometryObjects), model.nq))
    for g, geom in enumerate(geometry.geometryObjects):
        reach = float(np.linalg.norm(geom.placement.translation)) + bounding_radius(
            geom.geometry)
        joint = int(geom.parentJoint)
        while joint > 0:
            radii[g, model.joints[joint].idx_q] = reach
            reach += float(np.linalg.norm(model.jointPlacements[joint].translation))
            joint = int(model.parents[joint])
    return radii


def bounding_radius(shape: coal.CollisionGeometry) -> float:
    if isinstance(shape, coal.Box):
        return float(np.linalg.norm(shape.halfSide))
    if isinstance(shape, coal.Sphere):
        return float(shape.radius)
    if isinstance(shape, coal.Capsule):
        return float(shape.radius + shape.halfLength)
    if isinstance(shape, coal.Cylinder):
        return float(math.hypot(shape.radius, shape.halfLength))
    shape.computeLocalAABB()
    return float(shape.aabb_radius)


def coal_shape(solid: SolidSpec) -> coal.CollisionGeometry:
    size = solid.size
    if solid.shape is Shape.BOX:
        return coal.Box(2.0 * size[0], 2.0 * size[1], 2.0 * size[2])
    if solid.shape is Shape.SPHERE:
        return coal.Sphere(size[0])
    if solid.shape is Shape.CYLINDER:
        return coal.Cylinder(size[0], 2.0 * size[1])
    return coal.Capsule(size[0], 2.0 * size[1])


def placement(solid: SolidSpec) -> pin.SE3:
    return pin.SE3(pin.rpy.rpyToMatrix(*solid.rotation), np.array(solid.position, dtype=float))


__all__ = ["Shape", "SolidSpec", "arm_geometry", "bounding_radius", "coal_shape",
           "joint_axis", "joint_reach", "placement"]
