"""What a built cell hands its stand-ins: the manifest, the task's layout, the arm's model."""

from __future__ import annotations

from dataclasses import dataclass

from assurance.kinematics import ArmKinematics
from kernel.manifest import Manifest
from kernel.shell.gateway import CoreGateway
from skills.layout import CellLayout
from skills.planner import Planner


@dataclass(frozen=True, slots=True, eq=False)
class CellContext:
    manifest: Manifest
    layout: CellLayout
    planner: Planner
    """Solves tool poses on the arm's model (the reference policy's goal, the task's moves)."""
    kinematics: ArmKinematics
    gateway: CoreGateway
