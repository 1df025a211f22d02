"""``[geometry]``: where the cell's solids are, as the feasibility owner and the monitor read it.

The robot's own collision geometry is not written here: it is the primitive geoms of the arm's
model (``[robot] kinematics`` / ``model``), which the core loads as a Pinocchio
``GeometryModel`` and the independent monitor loads with its own code. This table adds what the
model does not know, each solid in the robot's base frame (metres, radians)::

    [geometry]
    margin_m = 0.01                   # clearance every checked pair keeps, unless a phase says
    self_collision = true             # non-adjacent links of the arm against each other

    [geometry.phase_margin_m]         # a phase's own clearance (phase names as in [phases])
    FREE_SPACE = 0.03
    CONTACT = 0.0

    [geometry.part]                   # the held part, attached to the TCP while the gripper holds
    shape = "box"
    size = [0.01, 0.01, 0.03]         # half extents, as MuJoCo writes a box
    position = [0.0, 0.0, 0.0175]     # its centre in the TCP frame

    [[geometry.obstacles]]            # solids the arm, the tool and the part must not touch
    name = "fixture"
    shape = "box"
    size = [0.026, 0.026, 0.015]
    position = [-0.55, -0.15, 0.015]
    allow_contact = ["CONTACT"]       # phases in which the tool and the part may touch it

    [[geometry.keep_out]]             # volumes nothing of the robot may enter, in any phase
    name = "operator_bench"
    shape = "box"
    size = [0.3, 0.5, 1.0]
    position = [0.2, 0.9, 1.0]

A shape's ``size`` follows MuJoCo's geoms: a box gives three half extents, a sphere its radius,
a cylinder or a capsule its radius and half length (along its own z axis). ``rotation`` turns
the solid about the fixed x, then y, then z axes of the base frame (roll, pitch, yaw; radians).

This module imports nothing of the core (``kernel.core``, ``assurance``, ``skills``), so the
safety monitor reads the very same table with the very same checks (tests/test_layers.py).
Which phase names exist is the core's knowledge: :mod:`kernel.manifest` checks the names in
``phase_margin_m`` and ``allow_contact``; the monitor checks keep-out zones in every phase and
does not read them.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from enum import StrEnum
from typing import Annotated, Any, TypeVar

import msgspec
from msgspec import Meta

from kernel.scenario.bounds import NAME_PATTERN, WORKSPACE_MAX_M
from kernel.scenario.fields import Where
from kernel.tables import read_table, typed

MARGIN_MAX_M = 0.5
"""No clearance is wider than half a metre: a larger one is a unit mistake (mm for m)."""

Coordinate = Annotated[float, Meta(ge=-WORKSPACE_MAX_M, le=WORKSPACE_MAX_M)]
HalfSize = Annotated[float, Meta(gt=0.0, le=WORKSPACE_MAX_M)]
"""A half extent or a radius, m: positive (a solid of no size hides nothing)."""
Angle = Annotated[float, Meta(ge=-7.0, le=7.0)]
"""A rotation angle, rad (one turn and a little: anything larger is a degrees mistake)."""
Margin = Annotated[float, Meta(ge=0.0, le=MARGIN_MAX_M)]


class Shape(StrEnum):
    BOX = "box"
    SPHERE = "sphere"
    CYLINDER = "cylinder"
    CAPSULE = "capsule"

    @property
    def size_count(self) -> int:
        """How many numbers ``size`` holds for this shape."""
        return {Shape.BOX: 3, Shape.SPHERE: 1}.get(self, 2)


class Solid(msgspec.Struct, frozen=True, kw_only=True):
    """One primitive solid, placed in the base frame (an obstacle or a keep-out zone)."""

    name: str
    shape: Shape
    size: tuple[HalfSize, ...]
    position: tuple[Coordinate, Coordinate, Coordinate]
    rotation: tuple[Angle, Angle, Angle] = (0.0, 0.0, 0.0)


class Obstacle(Solid, frozen=True, kw_only=True):
    """A solid of the cell the robot must keep its clearance from."""

    allow_contact: tuple[str, ...] = ()
    """Phases in which the tool and the held part may touch it (the fixture in CONTACT): those
    pairs are not checked then. The arm's links keep their clearance in every phase."""


class HeldPart(msgspec.Struct, frozen=True, kw_only=True):
    """The part the gripper holds, fixed to the TCP frame while the gripper is closed on it."""

    shape: Shape
    size: tuple[HalfSize, ...]
    position: tuple[Coordinate, Coordinate, Coordinate]
    """Its centre in the TCP frame, m."""
    rotation: tuple[Angle, Angle, Angle] = (0.0, 0.0, 0.0)


S = TypeVar("S", bound=Solid)


class GeometrySettings(msgspec.Struct, frozen=True, kw_only=True):
    """``[geometry]``: the cell's solids and the clearances kept from them."""

    margin_m: Margin = 0.01
    self_collision: bool = True
    phase_margin_m: dict[str, Margin] = msgspec.field(default_factory=dict)
    part: HeldPart | None = None
    obstacles: tuple[Obstacle, ...] = ()
    keep_out: tuple[Solid, ...] = ()

    def margin(self, phase: str) -> float:
        """The clearance kept in ``phase`` (its own, else the default)."""
        return self.phase_margin_m.get(phase, self.margin_m)


_SCALARS = ("margin_m", "self_collision")


def geometry_table(doc: Mapping[str, Any], where: Where) -> GeometrySettings | None:
    """``[geometry]`` of the document ``doc`` (None when it has none), every solid checked.

    Raises:
        ScenarioError: ``file: geometry.obstacles[1].size: why`` for an unknown or missing
            key, a value of the wrong type or out of range, a size that does not fit its
            shape, or two solids of one name.
    """
    if "geometry" not in doc:
        return None
    here = where.at("geometry")
    raw = doc["geometry"]
    if not isinstance(raw, dict):
        raise here.error("must be a table")
    known = {*_SCALARS, "phase_margin_m", "part", "obstacles", "keep_out"}
    for key in raw:
        if key not in known:
            raise here.at(key).error(f"unknown key (known: {', '.join(sorted(known))})")
    scalars = read_table(_Scalars, {k: raw[k] for k in _SCALARS if k in raw}, here)
    settings = GeometrySettings(
        margin_m=scalars.margin_m, self_collision=scalars.self_collision,
        phase_margin_m=_margins(raw.get("phase_margin_m", {}), here.at("phase_margin_m")),
        part=_part(raw["part"], here.at("part")) if "part" in raw else None,
        obstacles=_solids(Obstacle, raw.get("obstacles", []), here.at("obstacles")),
        keep_out=_solids(Solid, raw.get("keep_out", []), here.at("keep_out")))
    _unique_names(settings, here)
    return settings


class _Scalars(msgspec.Struct, frozen=True, kw_only=True):
    margin_m: Margin = 0.01
    self_collision: bool = True


def _margins(raw: Any, where: Where) -> dict[str, float]:
    if not isinstance(raw, dict):
        raise where.error("must be a table of phase = metres")
    return {phase: typed(value, Margin, where.at(phase)) for phase, value in raw.items()}


def _part(raw: Any, where: Where) -> HeldPart:
    if not isinstance(raw, dict):
        raise where.error("must be a table")
    part = read_table(HeldPart, raw, where)
    _check_size(part.shape, part.size, where)
    return part


def _solids(cls: type[S], raw: Any, where: Where) -> tuple[S, ...]:
    if not isinstance(raw, list):
        raise where.error("must be an array of tables ([[...]])")
    solids = []
    for index, entry in enumerate(raw):
        at = where.at(index)
        if not isinstance(entry, dict):
            raise at.error("must be a table")
        solid = read_table(cls, entry, at)
        if not re.fullmatch(NAME_PATTERN, solid.name):
            raise at.at("name").error(f"{solid.name!r} is not a name (letters, digits, '._-', "
                                      "at most 64)")
        _check_size(solid.shape, solid.size, at)
        solids.append(solid)
    return tuple(solids)


def _check_size(shape: Shape, size: tuple[float, ...], where: Where) -> None:
    if len(size) != shape.size_count:
        meaning = {Shape.BOX: "three half extents", Shape.SPHERE: "a radius"}.get(
            shape, "a radius and a half length")
        raise where.at("size").error(
            f"a {shape} takes {meaning} ({shape.size_count} value"
            f"{'s' if shape.size_count > 1 else ''}), got {len(size)}")


def _unique_names(settings: GeometrySettings, where: Where) -> None:
    seen: dict[str, str] = {}
    for key, solids in (("obstacles", settings.obstacles), ("keep_out", settings.keep_out)):
        for index, solid in enumerate(solids):
            if solid.name in seen:
                raise where.at(key).at(index).at("name").error(
                    f"{solid.name!r} already names {seen[solid.name]}")
            seen[solid.name] = f"{key}[{index}]"


__all__ = ["GeometrySettings", "HeldPart", "Obstacle", "Shape", "Solid", "geometry_table"]
