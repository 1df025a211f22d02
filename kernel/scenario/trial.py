"""The ``envelope`` section: a bounded trial's envelope, enforced by the core itself.

``envelope.workspace`` is a box ``{lower: [x, y, z], upper: [x, y, z]}`` (metres, base frame)
the tool centre point must stay in, commanded and measured; ``envelope.max_wrist_force_n`` the
largest wrist force. ``warden trial`` writes this section from the manifest's ``[trial]``, so
the journal's header carries it and a replay enforces the same bounds. It needs the arm's model
(``robot.kinematics`` or ``robot.model``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from assurance.kinematics import ArmKinematics, WorkspaceBox
from kernel.core.config import TrialBounds
from kernel.scenario.fields import Where, mapping, number, vector

FORCE_MAX_N = 1000.0
WORKSPACE_MAX_M = 100.0


def trial_bounds(doc: Mapping[str, Any], where: Where,
                 kinematics: ArmKinematics | None) -> TrialBounds | None:
    if doc.get("envelope") is None:
        return None
    here = where.at("envelope")
    envelope = mapping(doc, "envelope", where)
    if kinematics is None:
        raise here.error("needs the arm's model (robot.kinematics or robot.model) to know "
                         "where the tool is")
    box = mapping(envelope, "workspace", here)
    corners = here.at("workspace")
    lower = vector(box.get("lower"), corners.at("lower"), 3)
    upper = vector(box.get("upper"), corners.at("upper"), 3)
    for axis, (low, high) in enumerate(zip(lower, upper, strict=True)):
        if not (abs(low) <= WORKSPACE_MAX_M and abs(high) <= WORKSPACE_MAX_M and low < high):
            raise corners.at("lower").at(axis).error(
                f"{low} must be below upper[{axis}] = {high}, both within "
                f"{WORKSPACE_MAX_M:g} m")
    force = number(envelope, "max_wrist_force_n", here, positive=True, maximum=FORCE_MAX_N)
    if not math.isfinite(force):
        raise here.at("max_wrist_force_n").error("must be finite")
    return TrialBounds(WorkspaceBox(lower, upper), force)
