"""The assembly task of a cell, from the manifest's ``[task]`` table: where the parts are.

The cycle (:mod:`skills.assembly`) works in the robot's base frame with the geometry given
here: the arm's home pose, the tool's orientation for grasping and inserting, where the feeder
presents the part, where the hole is. It is calibration data of the cell, never code: a real
cell measures it, the simulated cell's manifests carry the simulated cell's values.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from assurance.kinematics import ArmKinematics
from drivers.settings import SettingsError, settings_from_mapping
from kernel.manifest import Manifest, ManifestError
from skills.assembly import AssemblyRunner
from skills.evaluator import Evaluator
from skills.layout import CellLayout
from skills.planner import Planner
from skills.trajectory import MotionLimits


@dataclass(frozen=True, slots=True)
class TaskSettings:
    """``[task]``: lengths in metres, angles in radians, base frame of the robot."""

    home_q: tuple[float, ...]
    """Joint angles the cycle starts from and returns to."""
    tool_rotation: tuple[tuple[float, float, float], tuple[float, float, float],
                         tuple[float, float, float]]
    """Tool orientation (rows of a 3x3 rotation) for every tool-down pose of the cycle."""
    part_position: tuple[float, float, float]
    """The part's centre where the feeder presents it."""
    hole_top: tuple[float, float, float]
    """Centre of the hole's opening on the fixture's top face."""
    hole_depth: float
    part_centre_below_tcp: float
    """Along the tool axis, from the TCP to the centre of a grasped part."""
    part_half_height: float
    gripper_open: float
    gripper_closed: float = 0.0
    clearance_height: float = 0.15
    """TCP height above a target for approach, lift and staging moves."""
    pre_insert_gap: float = 0.005
    """Gap between the part's bottom and the fixture top at the pre-insert pose."""
    lateral_tolerance_m: float = 0.002
    """VERIFY: the measured tool must end this close to the hole's axis."""
    max_insertion_force_n: float = 25.0
    """VERIFY: the wrist force measured during the insertion must stay below this."""

    def layout(self) -> CellLayout:
        return CellLayout(
            home_q=np.array(self.home_q), tool_down=np.array(self.tool_rotation),
            peg_start=np.array(self.part_position), hole_top=np.array(self.hole_top),
            peg_centre_below_tcp=self.part_centre_below_tcp,
            peg_half_height=self.part_half_height, hole_depth=self.hole_depth,
            gripper_open=self.gripper_open, gripper_closed=self.gripper_closed,
            clearance_height=self.clearance_height, pre_insert_gap=self.pre_insert_gap,
        )


def task_settings(manifest: Manifest) -> TaskSettings:
    """The manifest's ``[task]``, checked: every pose finite, the rotation a rotation."""
    table: Mapping[str, Any] = manifest.task
    where = f"{manifest.path}: task"
    try:
        settings = settings_from_mapping(TaskSettings, table, where)
    except SettingsError as error:
        raise ManifestError(str(error)) from None
    rotation = np.array(settings.tool_rotation)
    if not np.all(np.isfinite(rotation)) or not np.allclose(rotation @ rotation.T, np.eye(3),
                                                           atol=1e-6):
        raise ManifestError(f"{where}.tool_rotation: not a rotation matrix (rows orthonormal)")
    if len(settings.home_q) != int(manifest.core.limits.arm_mask.sum()):
        raise ManifestError(f"{where}.home_q: one angle per arm joint, "
                            f"{int(manifest.core.limits.arm_mask.sum())} here")
    return settings


def assembly_runner(manifest: Manifest, kinematics: ArmKinematics, limits: MotionLimits,
                    ground_truth: Any) -> AssemblyRunner:
    """The cycle's runner for this cell (the planner here only solves tool poses: the core
    plans and plays the moves); ``ground_truth`` is a simulator's extra check, or None."""
    settings = task_settings(manifest)
    layout = settings.layout()
    planner = Planner(kinematics, limits, layout.tool_down)
    evaluator = Evaluator(manifest.cell.insertion_tolerance_m, settings.lateral_tolerance_m,
                          settings.max_insertion_force_n)
    return AssemblyRunner(layout, planner, evaluator, ground_truth)
