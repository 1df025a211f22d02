"""The assembly task of a cell, from the manifest's ``[task]`` table: where the parts are.

The cycle (:mod:`skills.assembly`) works in the robot's base frame with the geometry given
here: the arm's home pose, the tool's orientation for grasping and inserting, where the feeder
presents the part, where the hole is. It is calibration data of the cell, never code: a real
cell measures it, the simulated cell's manifests carry the simulated cell's values.
"""

from __future__ import annotations

from typing import Any

from assurance.kinematics import ArmKinematics
from drivers.settings import read_table
from kernel.app.task_settings import TaskSettings
from kernel.manifest import Manifest, ManifestError
from kernel.scenario.fields import Where
from skills.assembly import AssemblyRunner
from skills.evaluator import Evaluator
from skills.planner import Planner
from skills.trajectory import MotionLimits

__all__ = ["TaskSettings", "assembly_runner", "check_task", "task_settings"]


def task_settings(manifest: Manifest) -> TaskSettings:
    """The manifest's ``[task]``, checked when the manifest was loaded (every value finite and
    within its physical bounds, the rotation a rotation, the home pose inside the joint
    limits).

    Raises:
        ManifestError: the manifest has no ``[task]``: naming the first key the task needs.
    """
    if manifest.task is not None:
        return manifest.task
    try:
        return read_table(TaskSettings, {}, Where(str(manifest.path), "task"))
    except ValueError as error:
        raise ManifestError(str(error)) from None


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
