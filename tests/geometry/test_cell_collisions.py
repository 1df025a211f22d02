"""Policies that press into the cell are refused with COLLISION, in the simulated cell and
through the UR RTDE driver and its emulator, judged by MuJoCo.

Each press (tools/cell_press.py) is the reference policy server heading for a goal inside the
cell's solids along a smooth joint-space line within every joint limit: the TCP 2 cm below the
table, the held peg 2 cm into the fixture's top, the upper arm into the table while the tool
stays high, the wrist folded into the upper arm. warden must refuse the chunks that would
take the arm there (reason COLLISION in the decision log), and the judge, MuJoCo's forward
kinematics and distances of the cell's own scene for every joint setpoint warden commanded while
the policy drove, never warden's Pinocchio or coal code, must find the arm, the tool and the
peg kept at the manifest's pre-contact clearance from what was pressed on.

TOLERANCE_M: the manifest's solids and the cell's scene are the same primitives (the fixture
a solid box over the cell's four walls), and the core's distances and MuJoCo's are exact for
them; 2 mm allows for the setpoint interpolation between checked actions being bounded, not
sampled, and for the fixture's solid box standing in for its walls.

One cell run per press and cell (about 17 s each on the 2-core test machine), shared by its
assertions: every press in the simulated cell, and the fixture press (the held part, the
phase's clearance) through the RTDE driver, which checks the same chunks with the same code
and adds the driver's path (the other three presses there cost 105 s of the suite's time and
told nothing the simulated cell's did not).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from kernel.cell_geometry import GeometrySettings, geometry_table
from kernel.scenario.fields import Where
from tools.cell_press import MANIFESTS, PRESSES, judge, run_press

pytestmark = pytest.mark.slow
TOLERANCE_M = 0.002
PHASE = "PRE_CONTACT"
JUDGED: dict[str, tuple[str, ...]] = {
    "table": ("peg_table", "arm_table"),
    "fixture": ("peg_fixture", "arm_fixture"),
    "elbow": ("arm_table",),
    "wrist": ("wrist_upper",),
}
"""Which of the judge's distances each press drives towards zero."""
PRESS_TIMEOUT_S = 15.0
"""s: the press's cycle ends here, not at the manifest's 30 s. The transport move and the
pre-contact approach's 8 s timeout fit in it; what follows a refused press (SAFE_HOLD, the
simulated operator's recovery, the press refused again) is what the judge reads, and the
second half of a 30 s cycle only repeated it (about 15 s of each run's 32)."""
CASES = [*((press, "sim-ur5e.toml") for press in sorted(JUDGED)),
         ("fixture", "sim-ur5e-rtde.toml")]


def _geometry(cell: str) -> GeometrySettings:
    path = MANIFESTS / cell
    geometry = geometry_table(tomllib.loads(path.read_text()), Where(str(path), ""))
    if geometry is None:
        pytest.fail(f"{cell} has no [geometry]: warden knows nothing of the cell's solids")
    return geometry


def _clearance(geometry: GeometrySettings, measure: str) -> float:
    """The clearance warden keeps in the pre-contact phase for what ``measure`` measures."""
    if measure == "wrist_upper":  # self-collision keeps the default clearance in every phase
        assert geometry.self_collision
        return geometry.margin_m
    solid = "table" if measure.endswith("table") else "fixture"
    [obstacle] = [o for o in geometry.obstacles if solid in o.name]
    assert PHASE not in obstacle.allow_contact
    return geometry.margin(PHASE)


@pytest.mark.parametrize(("press", "cell"), CASES)
def test_a_policy_pressing_into_the_cell_is_refused_with_collision(
        tmp_path: Path, press: str, cell: str) -> None:
    geometry = _geometry(cell)
    verdict = judge(run_press(PRESSES[press], cell, tmp_path, PRESS_TIMEOUT_S))
    print(f"{press} through {cell}: {verdict.setpoints} policy setpoints, lowest "
          f"{ {k: round(v, 4) for k, v in verdict.lowest.items()} }, refusals "
          f"{verdict.refusals}, e.g. {verdict.collision_details[:1]}")
    assert verdict.setpoints > 0, "the policy never drove"
    assert verdict.refusals.get("COLLISION", 0) > 0
    for measure in JUDGED[press]:
        clearance = _clearance(geometry, measure)
        assert verdict.lowest[measure] >= clearance - TOLERANCE_M, (measure, clearance)
    if press in ("table", "fixture"):
        assert verdict.below_peg_touch == 0
