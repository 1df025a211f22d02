"""Merge planning: trim, replace, append and blend, each followed by projection."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from assurance.envelope import Chunk, ReplacementPolicy
from assurance.event_chunk import decode_event_chunk
from assurance.gates import Timing
from assurance.limits import JointLimits
from assurance.merge import MergeInputs, MergePlan, plan_merge
from assurance.projection import Reference
from assurance.queue import ActionQueue, Segment
from tests.core.projection_oracle import violations

MS = 1_000_000
DT = 10 * MS
INF = float("inf")
FREE = JointLimits(np.full(2, -INF), np.full(2, INF), np.full(2, INF), np.full(2, INF))


def chunk(actions: list[list[float]], policy: str = "replace", first_ms: float = 0) -> Chunk:
    result = decode_event_chunk({
        "chunk_id": "new", "sequence": 2, "queue_epoch": 1, "policy_checkpoint": "ck",
        "config_hash": "cfg", "skill_version": "1", "task_phase": "FREE_SPACE",
        "controller_mode": "position", "calibration_epoch": 1, "observation_id": "o",
        "first_action_time": first_ms, "action_dt": DT / MS, "actions": actions,
        "replacement_policy": policy,
    }, client_receive=0)
    assert isinstance(result, Chunk)
    return result


def constant(value: float, rows: int) -> list[list[float]]:
    return [[value, value]] * rows


def segment(first_due: int, values: list[float], t_obs: int = 0, chunk_id: str = "old"
            ) -> Segment:
    actions = np.array([[v, v] for v in values], dtype=float)
    return Segment(chunk_id, 1, "FREE_SPACE", t_obs, 10**15, first_due, DT, actions, 0,
                   actions[0])  # arrives at rest: no step into row 0


def plan(queue: ActionQueue, new: Chunk, limits: JointLimits = FREE, *, trim: int = 0,
         t_obs: int = 0, blend_allowed: bool = True) -> MergePlan:
    first = new.time("first_action_time")
    timing = Timing((), first, trim, new.horizon, 10**15, trim)
    inputs = MergeInputs(new, timing, t_obs, 1, blend_allowed, np.zeros(2), np.zeros(2))
    return plan_merge(queue, inputs, limits)


def queued(*segments: Segment) -> ActionQueue:
    queue = ActionQueue()
    for s in segments:
        queue.push(s)
    return queue


def snapshot(queue: ActionQueue) -> list[tuple[str, int, int]]:
    return [(s.chunk_id, s.first_due, s.rows) for s in queue.segments]


# --- replace -----------------------------------------------------------------------------------


@given(st.integers(0, 15), st.integers(-5, 20), st.integers(1, 8))
def test_replace_displaces_exactly_the_rows_due_from_the_new_first_due(
    old_rows: int, start: int, new_rows: int
) -> None:
    queue = queued(segment(0, [0.0] * old_rows)) if old_rows else ActionQueue()
    result = plan(queue, chunk(constant(1.0, new_rows), first_ms=start * 10))
    due_later = sum(1 for r in range(old_rows) if r * DT >= start * DT)
    assert result.merge is ReplacementPolicy.REPLACE and result.cut_at == start * DT
    assert result.displaced == due_later
    result.commit(queue)
    kept = [s for s in queue.segments if s.chunk_id == "old"]
    assert sum(s.rows for s in kept) == old_rows - due_later
    assert queue.segments[-1].chunk_id == "new" and queue.segments[-1].first_due == start * DT


def test_planning_leaves_the_queue_untouched_until_commit() -> None:
    queue = queued(segment(0, [0.0] * 10))
    before = snapshot(queue)
    plan(queue, chunk(constant(1.0, 5), first_ms=30))
    assert snapshot(queue) == before


def test_trim_drops_the_late_prefix_and_shifts_the_schedule() -> None:
    result = plan(ActionQueue(), chunk([[float(i)] * 2 for i in range(5)]), trim=2)
    assert result.trimmed == 2
    assert result.segment.first_index == 2 and result.segment.first_due == 2 * DT
    np.testing.assert_array_equal(result.segment.actions[:, 0], [2.0, 3.0, 4.0])


def test_replacing_rows_from_a_newer_observation_is_flagged() -> None:
    queue = queued(segment(0, [0.0] * 10, t_obs=500))
    assert plan(queue, chunk(constant(0.0, 5), first_ms=30), t_obs=100).older_than_queue
    assert not plan(queue, chunk(constant(0.0, 5), first_ms=30), t_obs=600).older_than_queue
    # rows that already finished do not count
    assert not plan(queue, chunk(constant(0.0, 5), first_ms=200), t_obs=100).older_than_queue


# --- append ------------------------------------------------------------------------------------


def test_append_keeps_the_queue_and_skips_overlapping_rows() -> None:
    queue = queued(segment(0, [0.0] * 10))  # rows due 0..90 ms, ends at 100 ms
    result = plan(queue, chunk([[float(i)] * 2 for i in range(8)], "append", first_ms=50))
    assert result.merge is ReplacementPolicy.APPEND
    assert result.cut_at is None and result.displaced == 0 and not result.older_than_queue
    assert result.segment.first_due == 100 * MS and result.segment.first_index == 5
    np.testing.assert_array_equal(result.segment.actions[:, 0], [5.0, 6.0, 7.0])
    result.commit(queue)
    assert snapshot(queue) == [("old", 0, 10), ("new", 100 * MS, 3)]


def test_append_wholly_inside_the_queue_adds_nothing() -> None:
    queue = queued(segment(0, [0.0] * 10))
    result = plan(queue, chunk(constant(1.0, 3), "append", first_ms=20))
    assert result.segment.rows == 0
    result.commit(queue)
    assert snapshot(queue) == [("old", 0, 10)]


# --- blend -------------------------------------------------------------------------------------


def test_blend_not_allowed_degrades_to_replace() -> None:
    queue = queued(segment(0, [0.0] * 10))
    result = plan(queue, chunk(constant(1.0, 6), "blend", first_ms=50), blend_allowed=False)
    assert result.merge is ReplacementPolicy.REPLACE and not result.blended
    np.testing.assert_array_equal(result.segment.actions, np.ones((6, 2)))
    assert result.displaced == 5


@given(st.lists(st.floats(-2, 2), min_size=10, max_size=10),
       st.lists(st.floats(-2, 2), min_size=1, max_size=10), st.integers(0, 12))
def test_blended_rows_lie_between_old_and_new(
    old: list[float], new: list[float], start: int
) -> None:
    queue = queued(segment(0, old))
    result = plan(queue, chunk([[v, v] for v in new], "blend", first_ms=start * 10))
    assert result.blended == (start < len(old))
    for j, value in enumerate(result.segment.actions[:, 0]):
        k = start + j
        if k < len(old):
            lo, hi = sorted((old[k], new[j]))
            assert lo - 1e-12 <= value <= hi + 1e-12
        else:
            assert value == new[j]


def test_blend_weights_move_from_old_toward_new() -> None:
    queue = queued(segment(0, [0.0] * 10))
    result = plan(queue, chunk(constant(1.0, 5), "blend", first_ms=70))  # 3 rows overlap
    np.testing.assert_allclose(result.segment.actions[:, 0], [0.25, 0.5, 0.75, 1.0, 1.0])
    assert result.merge is ReplacementPolicy.BLEND and result.displaced == 3


# --- feasibility runs again --------------------------------------------------------------------

TIGHT = JointLimits.uniform(2, position=10.0, velocity=1.0, acceleration=1000.0)


def test_replace_is_projected_from_the_queued_predecessor() -> None:
    queue = queued(segment(0, [0.0] * 10))
    result = plan(queue, chunk(constant(0.5, 5), first_ms=50), TIGHT)
    # V = 1 rad/s * 10 ms: the jump from the queued 0.0 to 0.5 must become a ramp
    assert result.projection.max_distance > 0.4
    np.testing.assert_allclose(result.segment.actions[0], [0.01, 0.01])
    np.testing.assert_allclose(result.segment.step_into(0), [0.01, 0.01])


def test_an_empty_queue_projects_from_the_hold_position() -> None:
    result = plan(ActionQueue(), chunk(constant(0.5, 3), first_ms=0), TIGHT)
    np.testing.assert_allclose(result.segment.actions[:, 0], [0.01, 0.02, 0.03])


def admissible(actions: np.ndarray, ref: Reference, dt_s: float, limits: JointLimits) -> bool:
    """The independent oracle's verdict (tests/core/projection_oracle.py)."""
    return not violations(actions, ref.q, ref.step, dt_s, limits)


def test_an_infeasible_blend_shows_in_the_projection_distance() -> None:
    queue = queued(segment(0, [0.0] * 10))
    new = chunk(constant(0.5, 5), "blend", first_ms=50)
    at_new_start = Reference(np.full(2, 0.5), np.zeros(2))
    assert admissible(new.actions, at_new_start, DT * 1e-9, TIGHT)  # feasible on its own
    result = plan(queue, new, TIGHT)
    assert result.blended
    assert result.projection.max_distance > 0.1  # the cross-fade steps 0.1 rad per row
    assert admissible(result.segment.actions, Reference(np.zeros(2), np.zeros(2)),
                          DT * 1e-9, TIGHT)


GAP_BUG = ("plan_merge/_reference: when a chunk starts after a gap behind the queued rows "
           "(first_due > last row due + dt) the reference falls back to hold_q (the state "
           "measured at admission) instead of the last queued row, where the robot will hold "
           "during the gap; a jump back from that row is then queued unprojected")


@pytest.mark.parametrize("policy", ["append", "replace"])
def test_a_chunk_after_a_gap_is_projected_from_the_last_queued_row(policy: str) -> None:
    queue = queued(segment(0, [0.01 * (i + 1) for i in range(9)]))  # up to 0.09, ends 90 ms
    result = plan(queue, chunk(constant(0.0, 3), policy, first_ms=100), TIGHT)
    held_at_last_row = Reference(np.full(2, 0.09), np.zeros(2))
    assert admissible(result.segment.actions, held_at_last_row, DT * 1e-9, TIGHT)
