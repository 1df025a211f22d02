"""The workspace box: one type, one parser, one rule, wherever a file names a box.

A box is read from a scenario's ``robot.workspace`` and ``envelope.workspace``
(``{lower = [x, y, z], upper = [x, y, z]}``) and from a manifest's ``[trial]``
(``workspace_lower``, ``workspace_upper``). Everywhere: three coordinates per corner, each a
finite number within ±``WORKSPACE_MAX_M`` (m, base frame), and the lower corner strictly below
the upper one on every axis (a flat box holds no pose the arm can reliably reach: it is a
mistake, not a bound).
"""

from __future__ import annotations

from typing import Annotated, Any

from msgspec import Meta

from assurance.kinematics import WorkspaceBox
from kernel.scenario.bounds import FORCE_MAX_N, WORKSPACE_MAX_M
from kernel.scenario.fields import Where
from kernel.tables import typed

Coordinate = Annotated[float, Meta(ge=-WORKSPACE_MAX_M, le=WORKSPACE_MAX_M)]
"""One coordinate of a box corner, m, base frame."""
Corner = tuple[Coordinate, Coordinate, Coordinate]
WristForce = Annotated[float, Meta(ge=0.1, le=FORCE_MAX_N)]
"""A trial's wrist force limit, N (``[trial]`` and a scenario's ``envelope``): below 0.1 N the
sensor's noise alone would stop the arm."""


def workspace_box(lower: Any, upper: Any, where: Where, names: tuple[str, str]) -> WorkspaceBox:
    """The box whose corners ``lower`` and ``upper`` are written under ``where`` as the keys
    ``names`` (``("lower", "upper")`` or ``("workspace_lower", "workspace_upper")``).

    Raises:
        ScenarioError: naming the corner's key and axis.
    """
    low_at = where.at(names[0])
    low = typed(lower, Corner, low_at)
    high = typed(upper, Corner, where.at(names[1]))
    for axis, (a, b) in enumerate(zip(low, high, strict=True)):
        if not a < b:
            raise low_at.at(axis).error(f"{a:g} must be below {names[1]}[{axis}] = {b:g}")
    return WorkspaceBox(list(low), list(high))
