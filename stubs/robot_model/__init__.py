"""The simulated cell's robot model: file paths, joint names and the cell's nominal poses.

``manifests/models/ur5e.xml`` is the single source of truth for the arm: it is data the
manifests name (``robot.kinematics = "ur5e"``), Pinocchio loads it for the runtime, and MuJoCo
loads the same file (alone, or as the ``<include>`` of the simulated cell, ``cell.xml`` here).
The world frame of the cell is the arm's base frame (the real controller's "base" frame), with
the table top at z = 0.

The poses below mirror ``cell.xml``; ``tests/plant/test_mujoco_plant.py`` checks that they
agree with the compiled model, so edit both together.
"""

from __future__ import annotations

import math
from pathlib import Path

_HERE = Path(__file__).resolve().parent

ARM_MODEL: Path = _HERE.parents[1] / "manifests" / "models" / "ur5e.xml"
CELL_MODEL: Path = _HERE / "cell.xml"
CELL_ARM_INCLUDE = "ur5e.xml"
"""The file name ``cell.xml`` includes the arm by: the plant hands ``ARM_MODEL``'s bytes to
MuJoCo under this name."""

ARM_JOINT_NAMES: tuple[str, ...] = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
GRIPPER_JOINT_NAMES: tuple[str, str] = ("finger_left_joint", "finger_right_joint")
ARM_ACTUATOR_NAMES: tuple[str, ...] = (
    "shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3",
)
GRIPPER_ACTUATOR_NAME = "gripper"
GRIPPER_TENDON_NAME = "gripper_opening"
TCP_SITE = "tcp"
FT_SITE = "ft_site"
TOOL_BODY = "gripper"
"""The sensor measures the wrench between this body's subtree (the tool) and the arm."""
PAD_GEOMS: tuple[str, str] = ("pad_left", "pad_right")
PEG_BODY = "peg"
PEG_GEOM = "peg_geom"
HOLE_SITE = "hole_top"
FIXTURE_WALL_GEOMS: tuple[str, ...] = ("wall_px", "wall_nx", "wall_py", "wall_ny")

HOME_Q: tuple[float, ...] = (0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)
"""Upright arm, tool pointing down (-z), fingers closing along the base y axis."""
TOOL_DOWN_ROTATION: tuple[tuple[float, float, float], ...] = (
    (0.0, 1.0, 0.0),
    (1.0, 0.0, 0.0),
    (0.0, 0.0, -1.0),
)
"""TCP orientation at HOME_Q (rows of the matrix): tool z down, pads closing along base y.
Peg and hole faces are aligned with the base axes, so this is the grasp and insert
orientation."""

JOINT_VELOCITY_LIMIT: tuple[float, ...] = (math.pi,) * 6
"""rad/s. MJCF has no joint velocity limit, so it lives here (UR5e datasheet: 180 deg/s)."""
JOINT_EFFORT_LIMIT: tuple[float, ...] = (150.0, 150.0, 150.0, 28.0, 28.0, 28.0)
"""N·m, as ``actuatorfrcrange`` in ur5e.xml (size-3 and size-1 UR joints)."""

GRIPPER_MAX_OPENING = 0.085
"""Metres between the pads, fully open."""

PEG_HALF_EXTENTS: tuple[float, float, float] = (0.01, 0.01, 0.03)
PEG_START_POSITION: tuple[float, float, float] = (-0.40, 0.10, 0.03)
"""Peg centre, standing upright on the table, faces aligned with the base axes."""
HOLE_TOP_POSITION: tuple[float, float, float] = (-0.55, -0.15, 0.03)
"""Centre of the hole's opening, on the fixture's top face."""
HOLE_HALF_WIDTH = 0.01075
"""21.5 mm square hole for a 20 mm peg: 1.5 mm clearance, 0.75 mm a side."""
HOLE_DEPTH = 0.03

PEG_CENTRE_BELOW_TCP = 0.0175
"""Along the tool axis, from the TCP to the centre of a peg whose top is at the pads' top."""
