"""``[geometry]`` → the core's clearance checks (:class:`assurance.collision.CellCollision`).

The table itself is read by :func:`kernel.cell_geometry.geometry_table` (the safety monitor
reads it with the same function); here the names only the core knows are checked (a phase in
``phase_margin_m`` or in an obstacle's ``allow_contact`` must be a task phase), the robot
model's collision geoms are joined to the cell's solids, and the result goes into the core's
configuration. A manifest and a scenario file carry the table alike.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from assurance.collision import CellCollision, CollisionSettings, Shape, SolidSpec
from assurance.kinematics import ArmKinematics
from kernel.cell_geometry import GeometrySettings, HeldPart, Solid, geometry_table
from kernel.scenario.fields import Where
from skills.phases import TaskPhase


def cell_collision(doc: Mapping[str, Any], where: Where,
                   kinematics: ArmKinematics | None) -> CellCollision | None:
    """The clearance checks of the document's ``[geometry]`` (None: it has none).

    Raises:
        ScenarioError: naming the key: an unknown phase, a solid the table reader refuses, a
            robot without a model, or a model without collision geoms.
    """
    settings = geometry_table(doc, where)
    if settings is None:
        return None
    here = where.at("geometry")
    _check_phases(settings, here)
    if kinematics is None:
        raise here.error("needs the robot's model (robot.kinematics or robot.model): the "
                         "arm's own collision geoms come from it")
    try:
        return CellCollision(kinematics, collision_settings(settings))
    except ValueError as error:
        raise here.error(str(error)) from None


def collision_settings(settings: GeometrySettings) -> CollisionSettings:
    """The table as the core's plain data (the core does not import the kernel's types)."""
    solids = tuple(_solid(o, frozenset(o.allow_contact), keep_out=False)
                   for o in settings.obstacles)
    solids += tuple(_solid(z, frozenset(), keep_out=True) for z in settings.keep_out)
    return CollisionSettings(
        margin=settings.margin_m, phase_margins=dict(settings.phase_margin_m),
        self_collision=settings.self_collision,
        part=None if settings.part is None else _solid(settings.part, frozenset(), False),
        solids=solids)


def _solid(solid: Solid | HeldPart, allow: frozenset[str], keep_out: bool) -> SolidSpec:
    return SolidSpec(name=getattr(solid, "name", "part"), shape=Shape(str(solid.shape)),
                     size=tuple(solid.size), position=solid.position,
                     rotation=solid.rotation, allow_contact=allow, keep_out=keep_out)


def _check_phases(settings: GeometrySettings, where: Where) -> None:
    known = ", ".join(TaskPhase)
    for phase in settings.phase_margin_m:
        if phase not in TaskPhase.__members__:
            raise where.at("phase_margin_m").at(phase).error(
                f"unknown phase {phase!r} (expected one of {known})")
    for index, obstacle in enumerate(settings.obstacles):
        for position, phase in enumerate(obstacle.allow_contact):
            if phase not in TaskPhase.__members__:
                raise where.at("obstacles").at(index).at("allow_contact").at(position).error(
                    f"unknown phase {phase!r} (expected one of {known})")
