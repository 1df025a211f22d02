"""The robot model: a file the manifest names, read here and handed to the core as kinematics.

``robot.kinematics`` names a model that ships with warden (``"ur5e"``: the UR5e-class arm the
simulated cell runs, ``manifests/models/ur5e.xml``); ``robot.model`` names any MJCF (``.xml``)
or URDF (``.urdf``) file instead, relative to the manifest or scenario that names it, with
``robot.tcp_frame`` (the tool frame; a site in MJCF) and optionally ``robot.joints`` (the arm's
joints, base to tool; default: the model's first ``dof`` joints). Every other joint of the model
(a gripper's fingers) is locked.

A run's journal records the model file's absolute path and its SHA-256, so a replay reads the
very same model or refuses to run.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import pinocchio as pin

from assurance.kinematics import ArmKinematics, KinematicsConfig

MODELS_DIR = Path(__file__).resolve().parents[1] / "manifests" / "models"


@dataclass(frozen=True, slots=True)
class ModelSpec:
    path: Path
    tcp_frame: str
    joints: tuple[str, ...] | None = None
    """The arm's joints; None: the model's first ``dof`` joints."""


BUILTIN: dict[str, ModelSpec] = {
    "ur5e": ModelSpec(MODELS_DIR / "ur5e.xml", "tcp", (
        "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
        "wrist_2_joint", "wrist_3_joint")),
}


class ModelError(ValueError):
    """The model file cannot be read or does not describe the robot; the message says why."""


def digest(path: Path) -> str:
    """SHA-256 of the model file, hex (the journal records it)."""
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError as error:
        raise ModelError(f"cannot read {path}: {error.strerror or error}") from None


def load_kinematics(spec: ModelSpec, dof: int) -> ArmKinematics:
    """The arm's kinematics from ``spec``.

    Raises:
        ModelError: the file is missing or unreadable, is not MJCF or URDF, or lacks the
            joints or the tool frame.
    """
    model = _read(spec.path)
    names = [model.names[j] for j in range(1, model.njoints)]
    joints = spec.joints if spec.joints is not None else tuple(names[:dof])
    if len(joints) != dof:
        raise ModelError(f"{spec.path}: {len(joints)} arm joints for a robot of {dof}")
    try:
        return ArmKinematics(KinematicsConfig(model, spec.tcp_frame, joints, str(spec.path)))
    except ValueError as error:
        raise ModelError(str(error)) from None


def _read(path: Path) -> pin.Model:
    if not path.is_file():
        raise ModelError(f"{path}: no such model file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".xml":
            return pin.buildModelFromMJCF(str(path))
        if suffix == ".urdf":
            return pin.buildModelFromUrdf(str(path))
    except (RuntimeError, ValueError) as error:
        raise ModelError(f"{path}: not a readable model: {error}") from None
    raise ModelError(f"{path}: a robot model must be MJCF (.xml) or URDF (.urdf)")
