"""The ``envelope`` section: a bounded trial's envelope, enforced by the core itself.

``envelope.workspace`` is a box ``{lower: [x, y, z], upper: [x, y, z]}`` (metres, base frame)
the tool centre point must stay in, commanded and measured; ``envelope.max_wrist_force_n`` the
largest wrist force. ``warden trial`` writes this section from the manifest's ``[trial]``, so
the journal's header carries it and a replay enforces the same bounds. It needs the arm's model
(``robot.kinematics`` or ``robot.model``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from assurance.kinematics import ArmKinematics
from kernel.config.workspace import WristForce, workspace_box
from kernel.core.config import TrialBounds
from kernel.scenario.fields import Where, mapping
from kernel.tables import typed


def trial_bounds(doc: Mapping[str, Any], where: Where, kinematics: ArmKinematics | None,
                 given: TrialBounds | None = None) -> TrialBounds | None:
    """The envelope the ``envelope`` section of ``doc`` sets, or ``given`` (a live trial's,
    already typed from the manifest's ``[trial]``: not read back from a section)."""
    if given is None and doc.get("envelope") is None:
        return None
    here = where.at("envelope")
    if kinematics is None:
        raise here.error("needs the arm's model (robot.kinematics or robot.model) to know "
                         "where the tool is")
    if given is not None:
        return given
    envelope = mapping(doc, "envelope", where)
    box = mapping(envelope, "workspace", here)
    workspace = workspace_box(box.get("lower"), box.get("upper"), here.at("workspace"),
                              ("lower", "upper"))
    if "max_wrist_force_n" not in envelope:
        raise here.error("missing required key 'max_wrist_force_n'")
    force = typed(envelope["max_wrist_force_n"], WristForce, here.at("max_wrist_force_n"))
    return TrialBounds(workspace, force)
