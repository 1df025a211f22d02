"""The assembly task of a cell, from the manifest's ``[task]`` table: where the parts are.

The cycle (:mod:`skills.assembly`) works in the robot's base frame with the geometry given
here: the arm's home pose, the tool's orientation for grasping and inserting, where the feeder
presents the part, where the hole is. It is calibration data of the cell, never code: a real
cell measures it, the simulated cell's manifests carry the simulated cell's values.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from assurance.kinematics import ArmKinematics
from drivers.settings import SettingsError, settings_from_mapping
from kernel.manifest import Manifest, ManifestError
from kernel.scenario.bounds import LENGTH_MAX_M, WORKSPACE_MAX_M
from kernel.scenario.fields import ScenarioError, Where, number, vector
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
    """The manifest's ``[task]``, checked: every value finite and within its physical bounds,
    the rotation a rotation, the home pose inside the joint limits.

    Raises:
        ManifestError: naming the file and the key.
    """
    table: Mapping[str, Any] = manifest.task
    where = Where(str(manifest.path), "task")
    try:
        settings = settings_from_mapping(TaskSettings, table, f"{manifest.path}: task")
    except SettingsError as error:
        raise ManifestError(str(error)) from None
    try:
        _check_values(settings, where)
        _check_poses(settings, manifest, where)
    except ScenarioError as error:
        raise ManifestError(str(error)) from None
    return settings


_LENGTHS: dict[str, tuple[float, float]] = {
    "hole_depth": (1e-6, LENGTH_MAX_M),
    "part_centre_below_tcp": (-LENGTH_MAX_M, LENGTH_MAX_M),
    "part_half_height": (1e-6, LENGTH_MAX_M),
    "gripper_open": (0.0, LENGTH_MAX_M),
    "gripper_closed": (0.0, LENGTH_MAX_M),
    "clearance_height": (0.0, LENGTH_MAX_M),
    "pre_insert_gap": (0.0, LENGTH_MAX_M),
}
"""Metres: the range of every length of the task (a part, a stroke, a clearance)."""


def _check_values(settings: TaskSettings, where: Where) -> None:
    for key in ("home_q", "tool_rotation", "part_position", "hole_top"):
        flat = np.ravel(np.array(getattr(settings, key), dtype=float))
        if not np.all(np.isfinite(flat)):
            raise where.at(key).error("must hold finite numbers only")
    for key in ("part_position", "hole_top"):
        vector(list(getattr(settings, key)), where.at(key), 3, bound=WORKSPACE_MAX_M)
    for key, (low, high) in _LENGTHS.items():
        number(dataclasses.asdict(settings), key, where, minimum=low, maximum=high)
    if settings.gripper_open <= settings.gripper_closed:
        raise where.at("gripper_open").error(
            f"must exceed gripper_closed ({settings.gripper_closed:g}), got "
            f"{settings.gripper_open:g}")


def _check_poses(settings: TaskSettings, manifest: Manifest, where: Where) -> None:
    for index, row in enumerate(settings.tool_rotation):  # a rotation's entries are within ±1
        vector(list(row), where.at("tool_rotation").at(index), 3, bound=1.0 + 1e-6)
    rotation = np.array(settings.tool_rotation)
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6):
        raise where.at("tool_rotation").error("not a rotation matrix (rows orthonormal)")
    limits = manifest.core.limits
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


def check_task(manifest: Manifest) -> None:
    """Everything the assembly task needs from the manifest, checked before anything starts:
    the arm's model, and ``[task]``.

    Raises:
        ManifestError: naming the file and the key.
    """
    if manifest.core.kinematics is None:
        raise ManifestError(f"{manifest.path}: robot: the assembly task needs the arm's model "
                            "('kinematics' or 'model')")
    task_settings(manifest)


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
