"""``[task]``: the assembly task's layout, a frozen Struct read with the manifest.

Where the parts are is calibration data of the cell: the cycle (:mod:`skills.assembly`) works in
the robot's base frame with the geometry given here. Every field declares its range once; the
manifest loader reads the table with the one reader (:func:`drivers.settings.read_table`) and
then checks the home pose against the joint limits (:func:`check_home`), so a bad ``[task]``
is refused, naming the key, before anything starts (exit 2).
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from msgspec import Meta

from assurance.limits import JointLimits
from drivers.settings import KeyProblem, Settings
from kernel.config.workspace import Coordinate
from kernel.scenario.bounds import FORCE_MAX_N, LENGTH_MAX_M
from kernel.scenario.fields import Where
from skills.layout import CellLayout

Length = Annotated[float, Meta(ge=0.0, le=LENGTH_MAX_M)]
"""Metres: a part, a stroke, a clearance."""
PositiveLength = Annotated[float, Meta(ge=1e-6, le=LENGTH_MAX_M)]
Finite = Annotated[float, Meta()]
"""Any finite number (a home angle: :func:`check_home` checks it against the joint's limits)."""
RotationEntry = Annotated[float, Meta(ge=-1.0 - 1e-6, le=1.0 + 1e-6)]
"""A rotation's entries are within ±1 (and a little rounding)."""
Row = tuple[RotationEntry, RotationEntry, RotationEntry]
Point = tuple[Coordinate, Coordinate, Coordinate]


class TaskSettings(Settings, frozen=True, kw_only=True):
    """``[task]``: lengths in metres, angles in radians, base frame of the robot."""

    home_q: tuple[Finite, ...]
    """Joint angles the cycle starts from and returns to."""
    tool_rotation: tuple[Row, Row, Row]
    """Tool orientation (rows of a 3x3 rotation) for every tool-down pose of the cycle."""
    part_position: Point
    """The part's centre where the feeder presents it."""
    hole_top: Point
    """Centre of the hole's opening on the fixture's top face."""
    hole_depth: PositiveLength
    part_centre_below_tcp: Annotated[float, Meta(ge=-LENGTH_MAX_M, le=LENGTH_MAX_M)]
    """Along the tool axis, from the TCP to the centre of a grasped part."""
    part_half_height: PositiveLength
    gripper_open: Length
    gripper_closed: Length = 0.0
    clearance_height: Length = 0.15
    """TCP height above a target for approach, lift and staging moves."""
    pre_insert_gap: Length = 0.005
    """Gap between the part's bottom and the fixture top at the pre-insert pose."""
    lateral_tolerance_m: Annotated[float, Meta(gt=0.0, le=LENGTH_MAX_M)] = 0.002
    """VERIFY: the measured tool must end this close to the hole's axis."""
    max_insertion_force_n: Annotated[float, Meta(gt=0.0, le=FORCE_MAX_N)] = 25.0
    """VERIFY: the wrist force measured during the insertion must stay below this."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.gripper_open <= self.gripper_closed:
            raise KeyProblem("gripper_open", f"must exceed gripper_closed "
                             f"({self.gripper_closed:g}), got {self.gripper_open:g}")
        rotation = np.array(self.tool_rotation)
        if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6):
            raise KeyProblem("tool_rotation", "not a rotation matrix (rows orthonormal)")

    def layout(self) -> CellLayout:
        return CellLayout(
            home_q=np.array(self.home_q), tool_down=np.array(self.tool_rotation),
            peg_start=np.array(self.part_position), hole_top=np.array(self.hole_top),
            peg_centre_below_tcp=self.part_centre_below_tcp,
            peg_half_height=self.part_half_height, hole_depth=self.hole_depth,
            gripper_open=self.gripper_open, gripper_closed=self.gripper_closed,
            clearance_height=self.clearance_height, pre_insert_gap=self.pre_insert_gap,
        )


def check_home(settings: TaskSettings, limits: JointLimits, where: Where) -> None:
    """The home pose: one angle per arm joint, each inside its position limits.

    Raises:
        ScenarioError: naming ``task.home_q`` (and the joint).
    """
    arm = limits.arm_mask
    if len(settings.home_q) != int(arm.sum()):
        raise where.at("home_q").error(f"one angle per arm joint, {int(arm.sum())} here")
    home = np.array(settings.home_q)
    lower, upper = limits.lower[arm], limits.upper[arm]
    outside = np.flatnonzero((home < lower) | (home > upper))
    if outside.size:
        index = int(outside[0])
        raise where.at("home_q").at(index).error(
            f"{home[index]:g} is outside the position limits [{lower[index]:g}, "
            f"{upper[index]:g}]")
