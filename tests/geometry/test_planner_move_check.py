"""A planned move waits for its own clearance check, never for another move's.

Found in the simulated cell's second cycle: a resumed move asked for a clearance job, then the
task asked for the next move before the job answered; the answer (for the old move) cleared a
move that was no longer there, and the new move was never planned nor checked: the planner held
the arm still until the cycle's time ran out.
"""

from __future__ import annotations

import numpy as np

from kernel.core.events import MoveEvent, StateEvent
from kernel.core.lines import MotionLine
from skills.planner import MoveStatus
from tests.geometry.job_cell import JobCell
from tools.scenarios.catalog_collision import WRIST_START

HIGH = [0.0414, -1.7316, 2.0356, -1.8748, -1.5708, 0.0414]
"""The TCP 20 cm above the table, far from every solid."""


class Cell(JobCell):
    """The planner owns FREE_SPACE; the arm starts high, far from every solid."""

    def __init__(self) -> None:
        super().__init__("FREE_SPACE", "planner", HIGH)


def test_a_new_move_is_checked_and_played_though_the_last_ones_check_answers_late() -> None:
    cell = Cell()
    cell.step(StateEvent(t=0, q=tuple(HIGH)))
    first = np.array(HIGH) + np.array([0.2, 0.0, 0.0, 0.0, 0.0, 0.0])
    cell.step(MoveEvent(t=0, move_id=1, target=tuple(first.tolist())))
    cell.tick(50)
    [pending] = cell.asked  # the first move waits for its check
    second = np.array(HIGH) + np.array([-0.2, 0.0, 0.0, 0.0, 0.0, 0.0])
    cell.step(MoveEvent(t=cell.t, move_id=2, target=tuple(second.tolist())))
    cell.tick(5)
    cell.answer(pending)  # the first move's answer, after the second was asked for
    cell.tick(50)
    assert len(cell.asked) == 2, "the second move was never checked"
    assert np.allclose(cell.asked[1].rows[-1], second)
    cell.answer(cell.asked[1])
    cell.tick(2500)
    status = cell.core.status()
    assert (status.move_id, status.move) == (2, MoveStatus.FINISHED)
    assert np.allclose(cell.last.q, second, atol=1e-9)
    planned = [line.move_id for line in cell.lines
               if isinstance(line, MotionLine) and line.decision == "planned"]
    assert planned == [2]


def test_a_move_waits_for_its_own_check_not_for_the_answer_to_an_earlier_one() -> None:
    """The first move's clear answer plays nothing of the second, which waits at rest for its
    own check (towards the folded wrist: a move that must not play unchecked)."""
    cell = Cell()
    cell.step(StateEvent(t=0, q=tuple(HIGH)))
    first = np.array(HIGH) + np.array([0.1, 0.0, 0.0, 0.0, 0.0, 0.0])
    cell.step(MoveEvent(t=0, move_id=1, target=tuple(first.tolist())))
    cell.tick(50)
    [pending] = cell.asked
    cell.step(MoveEvent(t=cell.t, move_id=2, target=tuple(WRIST_START)))
    cell.answer(pending)
    cell.tick(200)
    assert len(cell.asked) == 2 and np.allclose(cell.asked[1].rows[-1], WRIST_START)
    assert not [line for line in cell.lines
                if isinstance(line, MotionLine) and line.decision == "planned"]
    assert np.allclose(cell.last.q, HIGH, atol=1e-9)
    assert cell.core.status().move is MoveStatus.WAITING
