"""The contact owner's force-aware retreat is checked before it starts, like its descent.

A force outside the contact phase's band (CONTACT_ANOMALY) hands the arm to CONTACT_FALLBACK:
the contact owner lifts the tool straight up, 2 cm from a hold. Where the cell has geometry
that path is a clearance job first, the contact owner holding where the arm was meanwhile; a
lift into something above the arm (here a hood 4.5 mm over its wrist) does not start.
MuJoCo's own distances (tests/geometry/oracle.py) judge the path, every millimetre.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest

from kernel.core.events import (
    ComputedEvent,
    ForceEvent,
    GripperEvent,
    OperatorAction,
    OperatorEvent,
    StateEvent,
)
from kernel.core.jobs import JobFailed
from kernel.core.lines import MotionLine
from skills.contact import RETREAT_LIFT_M, ContactState
from tests.geometry.job_cell import JobCell
from tests.geometry.oracle import MujocoOracle
from tools.scenarios.catalog_collision import FIXTURE_START, GEOMETRY

PHASE = "CONTACT"
CARD = {"force_band": 25.0}
FINE_M = 0.001


HOOD_Z = 0.312
"""The centre of a 60 × 60 × 1 cm plate over the tool at FIXTURE_START whose underside the arm's
highest point (its wrist, above the TCP) clears by 4.5 mm (found with the oracle): a hood over
the cell that a 2 cm lift runs into."""


def hooded() -> dict[str, Any]:
    geometry = copy.deepcopy(GEOMETRY)
    geometry["obstacles"].append({"name": "hood", "shape": "box", "size": [0.3, 0.3, 0.005],
                                  "position": [*TCP_XY, HOOD_Z]})
    return geometry


class Cell(JobCell):
    """A core in CONTACT holding the peg 2 cm above the fixture, jobs answered by the test."""

    def __init__(self, geometry: dict[str, Any] | None = None) -> None:
        super().__init__(PHASE, "contact", FIXTURE_START, card=CARD, geometry=geometry)
        self.step(GripperEvent(t=0, opening=0.0))
        self.step(StateEvent(t=0, q=tuple(FIXTURE_START)))
        self.tick(5)

    def anomaly(self) -> None:
        self.step(ForceEvent(t=self.t, residual=100.0))

    def tcp_z(self) -> float:
        kinematics = self.core.config.kinematics
        assert kinematics is not None
        return float(kinematics.forward(np.array(self.last.q)).position[2])

    def retreats(self) -> list[MotionLine]:
        return [line for line in self.lines
                if isinstance(line, MotionLine) and line.request == "retreat"]

    def lift(self) -> np.ndarray:
        """The path the law would lift along from here, every millimetre (for the oracle)."""
        contact = self.core.inspect_state().motion.contact
        plan = contact.plan_retreat(np.array(self.last.q))
        return contact.retreat_path(plan, FINE_M)


def _tcp_xy() -> tuple[float, float]:
    kinematics = Cell().core.config.kinematics
    assert kinematics is not None
    position = kinematics.forward(np.array(FIXTURE_START)).position
    return float(position[0]), float(position[1])


TCP_XY = _tcp_xy()


@pytest.fixture(scope="module")
def oracle() -> MujocoOracle:
    return MujocoOracle(GEOMETRY, held=True)


def test_a_clear_retreat_starts_once_it_is_checked(oracle: MujocoOracle) -> None:
    cell = Cell()
    assert min(oracle.slack(q, PHASE)[0] for q in cell.lift()) > 0.005  # the oracle: clear
    z_before = cell.tcp_z()
    cell.anomaly()
    cell.tick(20)
    [job] = cell.asked
    assert job.phase == PHASE and job.held and len(job.rows) == 4  # 2 cm in 5 mm steps
    assert cell.core.status().contact is ContactState.HOLDING
    assert cell.tcp_z() == pytest.approx(z_before, abs=1e-4)  # held while it is checked
    assert not cell.retreats()
    cell.answer(job)
    [line] = cell.retreats()
    assert line.decision == "started", line.detail
    cell.tick(1000)  # 2 s: 2 cm at 4 cm/s
    assert cell.core.status().contact is ContactState.RETREATED
    assert cell.tcp_z() == pytest.approx(z_before + RETREAT_LIFT_M, abs=1e-3)


def test_a_retreat_into_a_hood_is_refused_and_the_arm_holds() -> None:
    geometry = hooded()
    oracle = MujocoOracle(geometry, held=True)
    cell = Cell(geometry)
    slack, pair = min(oracle.slack(q, PHASE) for q in cell.lift())
    assert slack < -0.01 and "hood" in "".join(pair), (slack, pair)  # the oracle's verdict
    assert oracle.slack(np.array(FIXTURE_START), PHASE)[0] > 0.004  # where it is: clear
    z_before = cell.tcp_z()
    cell.anomaly()
    cell.tick(2)
    [job] = cell.asked
    cell.answer(job)
    cell.tick(1000)
    [line] = cell.retreats()
    assert line.decision == "refused" and (line.detail or "").startswith("COLLISION: ")
    assert "hood" in (line.detail or "")
    assert cell.tcp_z() == pytest.approx(z_before, abs=1e-4)
    assert cell.core.status().contact is ContactState.HOLDING
    assert len(cell.asked) == 1  # not asked again while the fallback lasts


def test_a_retreat_no_longer_commanded_starts_nothing() -> None:
    """The operator accepts recovery while the check runs: the pending retreat is refused
    (superseded), and its clear answer, arriving after, lifts nothing."""
    cell = Cell()
    cell.anomaly()
    cell.tick(2)
    [job] = cell.asked
    cell.step(OperatorEvent(t=cell.t, action=OperatorAction.ACCEPT_RECOVERY))
    cell.tick(2)
    [line] = cell.retreats()
    assert line.decision == "refused" and "no longer commanded" in (line.detail or "")
    z_before = cell.tcp_z()
    cell.answer(job)
    cell.tick(200)
    assert len(cell.retreats()) == 1
    assert cell.core.status().contact is not ContactState.RETREATING
    assert cell.tcp_z() == pytest.approx(z_before, abs=1e-3)


def test_a_check_that_could_not_run_is_asked_again_for_the_same_retreat() -> None:
    """A job that failed (the worker busy or restarting) is not a COLLISION: the contact owner
    holds, the same retreat is asked again 100 ms later, and starts once it is cleared."""
    cell = Cell()
    z_before = cell.tcp_z()
    cell.anomaly()
    cell.tick(1)
    [first] = cell.asked
    cell.step(ComputedEvent(t=cell.t, result=JobFailed(job_id=first.job_id, detail="busy")))
    [line] = cell.retreats()
    assert line.decision == "refused" and "asked again in 100 ms" in (line.detail or "")
    cell.tick(40)  # 80 ms: not yet
    assert len(cell.asked) == 1 and cell.core.status().contact is ContactState.HOLDING
    cell.tick(20)
    [_, second] = cell.asked
    assert second.rows == first.rows and second.start == first.start
    cell.answer(second)
    assert cell.retreats()[-1].decision == "started"
    cell.tick(1000)
    assert cell.tcp_z() == pytest.approx(z_before + RETREAT_LIFT_M, abs=1e-3)
