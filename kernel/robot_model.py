"""The robot model: a file the manifest names, read here and handed to the core as kinematics.

``robot.kinematics`` names a model that ships with warden (``"ur5e"``: the UR5e-class arm the
simulated cell runs, ``manifests/models/ur5e.xml``); ``robot.model`` names any MJCF (``.xml``)
or URDF (``.urdf``) file instead, relative to the manifest or scenario that names it, with
``robot.tcp_frame`` (the tool frame; a site in MJCF) and optionally ``robot.joints`` (the arm's
joints, base to tool; default: the model's first ``dof`` joints). Every other joint of the model
(a gripper's fingers) is locked.

A run's journal records the model file's absolute path and its SHA-256, so a replay reads the
very same model or refuses to run. The file is read once: the bytes hashed are the bytes parsed
(a file or symlink swapped during start-up can never pair one model with another's digest), so a
model must be one self-contained file (an MJCF ``<include>`` is refused by the parser).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import replace
from pathlib import Path

import pinocchio as pin

from assurance.kinematics import ArmKinematics, KinematicsConfig
from kernel.model_file import ModelSpec


class ModelError(ValueError):
    """The model file cannot be read or does not describe the robot; the message says why."""


def read_model(path: Path) -> tuple[bytes, str]:
    """The model file's bytes, read once, and their SHA-256 (hex; the journal records it).

    Raises:
        ModelError: the file is missing, not a regular file, or unreadable.
    """
    if not path.is_file():
        raise ModelError(f"{path}: no such model file")
    try:
        content = path.read_bytes()
    except OSError as error:
        raise ModelError(f"cannot read {path}: {error.strerror or error}") from None
    return content, hashlib.sha256(content).hexdigest()


def digest(path: Path) -> str:
    """SHA-256 of the model file, hex (for messages only: a loaded model carries the digest of
    the bytes it was parsed from, ``KinematicsConfig.sha256``)."""
    return read_model(path)[1]


def load_kinematics(spec: ModelSpec, dof: int) -> ArmKinematics:
    """The arm's kinematics from ``spec``, parsed from the one read of the file whose digest
    the result carries (``config.sha256``).

    Raises:
        ModelError: the file is missing or unreadable, is not MJCF or URDF, or lacks the
            joints or the tool frame.
    """
    content, sha256 = read_model(spec.path)
    model, collision = _parse(spec.path, content)
    names = [model.names[j] for j in range(1, model.njoints)]
    joints = spec.joints if spec.joints is not None else tuple(names[:dof])
    if len(joints) != dof:
        raise ModelError(f"{spec.path}: {len(joints)} arm joints for a robot of {dof}")
    config = KinematicsConfig(model, spec.tcp_frame, joints, str(spec.path),
                              collision=collision)
    try:
        return ArmKinematics(replace(config, sha256=sha256))
    except ValueError as error:
        raise ModelError(str(error)) from None


def _parse(path: Path, content: bytes) -> tuple[pin.Model, pin.GeometryModel | None]:
    """Pinocchio's model from ``content`` (``path`` names it in errors and picks the format),
    and its collision geoms (an MJCF's primitive geoms; None for a URDF, whose meshes are
    other files)."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".xml":
            return _parse_mjcf(content)
        if suffix == ".urdf":
            return pin.buildModelFromXML(content.decode("utf-8")), None
    except (RuntimeError, ValueError) as error:  # UnicodeDecodeError is a ValueError
        raise ModelError(f"{path}: not a readable model: {error}") from None
    raise ModelError(f"{path}: a robot model must be MJCF (.xml) or URDF (.urdf)")


def _parse_mjcf(content: bytes) -> tuple[pin.Model, pin.GeometryModel]:
    # Pinocchio's Python binding parses MJCF only from a path: hand it an anonymous in-memory
    # file holding the bytes already hashed, never the model's own path (which could name
    # another file by now).
    fd = os.memfd_create("warden-robot-model", os.MFD_CLOEXEC)
    try:
        written = 0
        while written < len(content):
            written += os.write(fd, content[written:])
        model = pin.buildModelFromMJCF(f"/proc/self/fd/{fd}")
        return model, pin.buildGeomFromMJCF(model, f"/proc/self/fd/{fd}",
                                            pin.GeometryType.COLLISION)
    finally:
        os.close(fd)
