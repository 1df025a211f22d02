"""The monitor's space check: the measured arm against the cell's keep-out zones and obstacles.

Its own code path, not warden's: the arm's model (``[robot] kinematics`` / ``model``, resolved by
the monitor's view) is loaded by MuJoCo here, never by Pinocchio, and the distances are
MuJoCo's collision detection (``mj_kinematics`` + ``mj_collision``), not the core's coal
queries. The solids are ``[geometry]`` (:mod:`kernel.cell_geometry`, the same table the core
reads), added to the model's world as geoms through ``mujoco.MjSpec``.

What is checked, on every sample the monitor reads (the measured arm joints), for every moving
geom of the arm's model (the model's primitive geoms on bodies below the first joint):

- against each keep-out zone: inside it at all is a breach, for any geom;
- against each obstacle: closer than the smallest clearance any phase keeps (``margin_m`` and
  every ``phase_margin_m``) is a breach. The monitor does not know the phase, so it holds the
  arm to the loosest clearance warden itself could have commanded. The tool (the body that
  carries the TCP site, and every body below it: the gripper and its fingers) is checked only
  against the obstacles no phase may touch (``allow_contact`` empty): the monitor cannot tell
  the contact phase from another. The arm's links are checked against every obstacle, as
  warden keeps them clear in every phase.

What is not: the held part (the monitor does not know whether the gripper holds one), the
tool against an obstacle some phase may touch, the arm against itself, and the fingers'
opening (they are placed at the model's reference, closed: a pad moves at most its finger's
travel sideways from there).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from kernel.cell_geometry import GeometrySettings, Shape, Solid
from kernel.model_file import ModelSpec
from kernel.safety.checks import Breach, Finding

LINK_BIT, TOOL_BIT = 1, 2
"""Contact masks: a link's geom has contype LINK_BIT, the tool's TOOL_BIT, both conaffinity 0;
a solid has contype 0 and conaffinity LINK_BIT (an obstacle some phase may touch) or
LINK_BIT | TOOL_BIT: MuJoCo pairs two geoms only where one's contype meets the other's
conaffinity, so never two arm geoms, never two solids, never the tool and a touchable
obstacle."""
_TYPES = {Shape.BOX: mujoco.mjtGeom.mjGEOM_BOX, Shape.SPHERE: mujoco.mjtGeom.mjGEOM_SPHERE,
          Shape.CYLINDER: mujoco.mjtGeom.mjGEOM_CYLINDER,
          Shape.CAPSULE: mujoco.mjtGeom.mjGEOM_CAPSULE}

_ONE_DOF = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


class SpaceModelError(ValueError):
    """The arm's model cannot be loaded for the space check; the message says why."""


@dataclass(frozen=True, slots=True)
class _Checked:
    name: str
    keep_out: bool
    clearance: float
    tool: bool
    """The tool is checked against it too."""


def clearance_of(geometry: GeometrySettings) -> float:
    """The smallest clearance any phase keeps from an obstacle (the default's, or a phase's)."""
    return min([geometry.margin_m, *geometry.phase_margin_m.values()])


def checked_solids(geometry: GeometrySettings) -> list[tuple[Solid, _Checked]]:
    """Every solid the monitor checks, with how: the keep-out zones and the obstacles."""
    clearance = clearance_of(geometry)
    zones = [(zone, _Checked(zone.name, True, 0.0, True)) for zone in geometry.keep_out]
    return zones + [(obstacle, _Checked(obstacle.name, False, clearance,
                                        not obstacle.allow_contact))
                    for obstacle in geometry.obstacles]


class SpaceCheck:
    """The arm's model with the checked solids in its world; :meth:`findings` judges one
    measured configuration."""

    def __init__(self, arm: ModelSpec, dof: int, geometry: GeometrySettings) -> None:
        """Raises:
            SpaceModelError: the file is unreadable, not a model MuJoCo compiles, or lacks
                the arm's joints.
        """
        spec = _spec(arm.path)
        for geom in spec.geoms:
            geom.contype, geom.conaffinity, geom.margin, geom.gap = LINK_BIT, 0, 0.0, 0.0
        spec.option.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        self._solids: dict[str, _Checked] = {}
        for solid, how in checked_solids(geometry):
            name = f"warden-safety/{solid.name}"
            spec.worldbody.add_geom(
                name=name, type=_TYPES[solid.shape], size=_size(solid.shape, solid.size),
                pos=list(solid.position), quat=_quaternion(solid.rotation),
                contype=0, conaffinity=LINK_BIT | (TOOL_BIT if how.tool else 0),
                margin=how.clearance)
            self._solids[name] = how
        try:
            self.model = spec.compile()
        except ValueError as error:
            raise SpaceModelError(f"{arm.path}: MuJoCo cannot compile it: {error}") from None
        for geom in _tool_geoms(self.model, arm):
            self.model.geom_contype[geom] = TOOL_BIT
        self.data = mujoco.MjData(self.model)
        self._solid_ids = {mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, name): how
                           for name, how in self._solids.items()}
        self.dof = dof
        self.qpos = _arm_addresses(self.model, arm, dof)
        self.solids = tuple(how.name for how in self._solids.values())

    def findings(self, q: Sequence[float]) -> list[Finding]:
        """One finding per solid the arm at ``q`` is inside (a keep-out zone) or closer to
        than the clearance (an obstacle), naming the deepest link; none for a reading that is
        not a configuration of this arm (the joint checks report it)."""
        if len(q) != self.dof or not all(math.isfinite(v) for v in q):
            return []
        self.data.qpos[self.qpos] = q
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_collision(self.model, self.data)
        count = self.data.ncon
        # The contact list's arrays, not its items: iterating MjContactList costs a
        # millisecond even when it is empty.
        pairs, dists = self.data.contact.geom[:count], self.data.contact.dist[:count]
        deepest: dict[int, tuple[float, int]] = {}
        for (first, second), dist in zip(pairs.tolist(), dists.tolist(), strict=True):
            solid, arm = (first, second) if first in self._solid_ids else (second, first)
            how = self._solid_ids.get(solid)
            if how is None or dist >= how.clearance:
                continue
            if solid not in deepest or dist < deepest[solid][0]:
                deepest[solid] = (dist, arm)
        return [self._finding(solid, dist, arm) for solid, (dist, arm) in sorted(deepest.items())]

    def _finding(self, solid: int, dist: float, arm: int) -> Finding:
        how = self._solid_ids[solid]
        body = self.model.body(self.model.geom_bodyid[arm]).name or f"body {arm}"
        if how.keep_out:
            return Finding(Breach.SPACE, f"{body} is {-dist:.3f} m inside keep-out zone "
                           f"{how.name!r}")
        where = f"{-dist:.3f} m into" if dist < 0 else f"{dist:.3f} m from"
        return Finding(Breach.SPACE, f"{body} is {where} obstacle {how.name!r} (clearance "
                       f"{how.clearance:g} m)")


def _spec(path: Path) -> mujoco.MjSpec:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, ValueError) as error:
        raise SpaceModelError(f"cannot read {path}: {getattr(error, 'strerror', None) or error}"
                              ) from None
    try:
        return mujoco.MjSpec.from_string(text)
    except ValueError as error:
        raise SpaceModelError(f"{path}: not a model MuJoCo reads: {error}") from None


def _tool_geoms(model: mujoco.MjModel, arm: ModelSpec) -> list[int]:
    """The geoms of the body that carries the TCP site (or is the TCP frame) and of every body
    below it."""
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, arm.tcp_frame)
    body = int(model.site_bodyid[site]) if site >= 0 else mujoco.mj_name2id(
        model, mujoco.mjtObj.mjOBJ_BODY, arm.tcp_frame)
    if body <= 0:
        raise SpaceModelError(f"{arm.path}: no site or body {arm.tcp_frame!r} (the TCP frame) "
                              "on the arm")

    def below(b: int) -> bool:
        while b > 0:
            if b == body:
                return True
            b = int(model.body_parentid[b])
        return False

    return [g for g in range(model.ngeom) if below(int(model.geom_bodyid[g]))]


def _arm_addresses(model: mujoco.MjModel, arm: ModelSpec, dof: int) -> np.ndarray:
    names = arm.joints if arm.joints is not None else tuple(
        model.joint(j).name for j in range(min(dof, model.njnt)))
    if len(names) != dof:
        raise SpaceModelError(f"{arm.path}: {len(names)} arm joints for a robot of {dof}")
    addresses = []
    for name in names:
        joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if joint < 0:
            raise SpaceModelError(f"{arm.path}: no joint {name!r}")
        if int(model.jnt_type[joint]) not in _ONE_DOF:
            raise SpaceModelError(f"{arm.path}: joint {name!r} is not a hinge or a slide")
        addresses.append(int(model.jnt_qposadr[joint]))
    return np.array(addresses)


def _size(shape: Shape, size: tuple[float, ...]) -> list[float]:
    """MuJoCo's three size numbers for ``size`` as the manifest writes it (MuJoCo's meaning)."""
    return [*size, *[0.0] * (3 - len(size))] if shape is not Shape.BOX else list(size)


def _quaternion(rotation: tuple[float, float, float]) -> list[float]:
    """Roll about the fixed x, then pitch about the fixed y, then yaw about the fixed z: the
    quaternion q_z * q_y * q_x (w, x, y, z)."""
    roll, pitch, yaw = (angle / 2 for angle in rotation)
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy]


__all__ = ["SpaceCheck", "SpaceModelError", "checked_solids", "clearance_of"]
