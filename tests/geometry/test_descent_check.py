"""The contact owner's descent is checked before it starts, like a planned move.

An ``insert`` asks for a guarded descent down to a height; in CONTACT the tool and the part may
touch the fixture, but nothing may go into the table, and no link may touch the fixture. The
descent's path is the law's own IK solutions, so the configurations judged here are the ones
the law would command; MuJoCo's own distances (tests/geometry/oracle.py) say whether they break
a clearance, sampled every millimetre of the descent.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from kernel.core.events import (
    ComputedEvent,
    ControllerEvent,
    ControllerStatus,
    GripperEvent,
    InsertEvent,
    StateEvent,
)
from kernel.core.jobs import JobFailed
from kernel.core.lines import MotionLine
from skills.contact import ContactState, Descent, DescentStatus
from tests.geometry.job_cell import JobCell
from tests.geometry.oracle import MujocoOracle
from tools.scenarios.catalog_collision import FIXTURE_START, GEOMETRY, TABLE_START

PHASE = "CONTACT"
HOLE_XY = (-0.55, -0.15)
"""The fixture's centre, where its hole is (GEOMETRY's fixture)."""
PEG_BELOW_TCP = 0.0475
"""The held peg's bottom under the TCP (GEOMETRY's part: its centre 17.5 mm down, a box of
half-extent 30 mm along the tool's axis)."""
FINE_M = 0.001


class Cell(JobCell):
    """A core in CONTACT holding the peg, whose jobs wait until the test answers them."""

    def __init__(self, start: list[float]) -> None:
        super().__init__(PHASE, "contact", start)
        self.step(GripperEvent(t=0, opening=0.0))
        self.step(StateEvent(t=0, q=tuple(start)))
        self.tick(5)

    def insert(self, xy: tuple[float, float], z_end: float) -> None:
        rotation = self.tcp().rotation
        self.step(InsertEvent(t=self.t, xy=xy, z_end=z_end,
                              rotation=tuple(rotation.ravel().tolist())))

    def tcp(self) -> Any:
        kinematics = self.core.config.kinematics
        assert kinematics is not None
        return kinematics.forward(np.array(self.last.q))

    def inserts(self) -> list[MotionLine]:
        return [line for line in self.lines
                if isinstance(line, MotionLine) and line.request == "insert"]

    def descent(self, xy: tuple[float, float], z_end: float) -> np.ndarray:
        """The path the law would follow, every millimetre (for the oracle)."""
        contact = self.core.inspect_state().motion.contact
        start = np.array(self.last.q)
        return contact.descent_path(Descent(start, np.array(xy), z_end, self.tcp().rotation),
                                    FINE_M)


@pytest.fixture(scope="module")
def oracle() -> MujocoOracle:
    return MujocoOracle(GEOMETRY, held=True)


def _lowest_slack(oracle: MujocoOracle, path: np.ndarray) -> tuple[float, tuple[str, str]]:
    return min(oracle.slack(q, PHASE) for q in path)


def test_a_descent_into_the_table_is_refused_and_the_arm_holds(oracle: MujocoOracle) -> None:
    """15 cm from the fixture, the peg driven 2 cm into the table top."""
    cell = Cell(TABLE_START)
    xy = tuple(cell.tcp().position[:2].tolist())
    z_end = PEG_BELOW_TCP - 0.02
    slack, pair = _lowest_slack(oracle, cell.descent(xy, z_end))
    assert slack < -0.015 and "table" in "".join(pair), (slack, pair)  # the oracle's verdict
    z_before = cell.tcp().position[2]
    cell.insert(xy, z_end)
    assert not cell.inserts()  # nothing is decided before the check answers
    cell.tick(20)
    [job] = cell.asked
    assert job.phase == PHASE and job.held
    cell.answer(job)
    cell.tick(500)  # 1 s: a started descent at 3 cm/s would be 3 cm down by now
    [line] = cell.inserts()
    assert line.decision == "refused" and line.detail is not None
    assert line.detail.startswith("COLLISION: ") and "table" in line.detail
    assert cell.tcp().position[2] == pytest.approx(z_before, abs=1e-4)
    assert cell.core.status().contact is ContactState.HOLDING


def test_a_descent_into_the_hole_starts_once_it_is_cleared(oracle: MujocoOracle) -> None:
    """Above the hole, down to the peg's bottom 3 mm above the table (the skill's insertion):
    the tool and the part may touch the fixture in CONTACT, and nothing comes near the table."""
    cell = Cell(FIXTURE_START)
    z_end = PEG_BELOW_TCP + 0.003
    slack, pair = _lowest_slack(oracle, cell.descent(HOLE_XY, z_end))
    assert slack > 0.002, (slack, pair)
    cell.insert(HOLE_XY, z_end)
    cell.tick(20)
    assert cell.tcp().position[2] > FIXTURE_START_TCP_Z - 1e-3  # held while it is checked
    [job] = cell.asked
    cell.answer(job)
    cell.tick(3)
    [line] = cell.inserts()
    assert line.decision == "started", line.detail
    assert cell.core.status().contact is ContactState.DESCENDING
    cell.tick(500)
    assert cell.tcp().position[2] < FIXTURE_START_TCP_Z - 0.01  # it goes down


def test_through_the_hole_into_the_table_is_refused(oracle: MujocoOracle) -> None:
    """The same descent taken 8 mm deeper: the peg's bottom 5 mm inside the table."""
    cell = Cell(FIXTURE_START)
    z_end = PEG_BELOW_TCP - 0.005
    slack, pair = _lowest_slack(oracle, cell.descent(HOLE_XY, z_end))
    assert slack < -0.004 and "table" in "".join(pair), (slack, pair)
    cell.insert(HOLE_XY, z_end)
    cell.tick(2)
    [job] = cell.asked
    cell.answer(job)
    [line] = cell.inserts()
    assert line.decision == "refused" and "table" in (line.detail or "")


def test_a_check_that_cannot_run_refuses_the_descent() -> None:
    cell = Cell(FIXTURE_START)
    cell.insert(HOLE_XY, PEG_BELOW_TCP + 0.003)
    [job] = cell.asked
    cell.step(ComputedEvent(t=cell.t, result=JobFailed(job_id=job.job_id, detail="worker died")))
    [line] = cell.inserts()
    assert line.decision == "refused" and "not checked" in (line.detail or "")
    assert cell.core.status().contact is ContactState.HOLDING


def test_an_earlier_inserts_answer_starts_nothing() -> None:
    """Two inserts before the first is answered: the first is superseded (its line says so),
    its clear answer is not the second's (which goes into the table), and only the second's
    answer decides."""
    cell = Cell(FIXTURE_START)
    cell.insert(HOLE_XY, PEG_BELOW_TCP + 0.003)
    cell.insert(HOLE_XY, PEG_BELOW_TCP - 0.02)
    first, second = cell.asked
    [superseded] = cell.inserts()
    assert superseded.decision == "refused" and "later insert" in (superseded.detail or "")
    cell.answer(first)
    cell.tick(50)
    assert len(cell.inserts()) == 1 and cell.core.status().contact is ContactState.HOLDING
    assert cell.core.status().descent is DescentStatus.CHECKING
    cell.answer(second)
    assert [line.decision for line in cell.inserts()] == ["refused", "refused"]
    assert "COLLISION" in (cell.inserts()[1].detail or "")
    assert cell.core.status().descent is DescentStatus.REFUSED


def test_a_clear_answer_after_the_arm_was_taken_starts_nothing() -> None:
    """An E-stop while the check runs: the clear answer finds the contact owner not in
    control, and the descent never starts."""
    cell = Cell(FIXTURE_START)
    cell.insert(HOLE_XY, PEG_BELOW_TCP + 0.003)
    [job] = cell.asked
    cell.step(ControllerEvent(t=cell.t, status=ControllerStatus.ESTOP))
    cell.answer(job)
    [line] = cell.inserts()
    assert line.decision == "refused" and "not in control" in (line.detail or "")
    assert cell.core.status().contact is not ContactState.DESCENDING
    cell.insert(HOLE_XY, PEG_BELOW_TCP + 0.003)  # and no new one is taken up meanwhile
    assert len(cell.asked) == 1 and cell.inserts()[-1].decision == "refused"


def test_a_descent_longer_than_an_insertion_is_refused_before_any_work() -> None:
    cell = Cell(FIXTURE_START)
    cell.insert(HOLE_XY, -1e6)  # a path of 10^8 samples, were it computed
    [line] = cell.inserts()
    assert line.decision == "refused" and "longer than 0.5 m" in (line.detail or "")
    assert not cell.asked


FIXTURE_START_TCP_Z = 0.015 + 0.015 + 0.02 + PEG_BELOW_TCP
"""The fixture's top (its centre 15 mm up, half-extent 15 mm), the peg's bottom 2 cm above
it."""
