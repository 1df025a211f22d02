"""The setpoint a merged chunk is projected from: direct tests of two rules of
``assurance/merge.py`` that only whole-scenario runs exercised before (issue 15, item 14).

- A reference step taken from a queued row on another action interval is rescaled to the new
  chunk's interval: the same velocity, so the acceleration bound holds across the change.
- With nothing queued and no hold, the measured state is clipped into the limits before it
  is projected from (a joint measured outside them is not a place to command from).
"""

from __future__ import annotations

import numpy as np

from assurance.envelope import Chunk
from assurance.event_chunk import decode_event_chunk
from assurance.gates import Timing
from assurance.limits import JointLimits
from assurance.merge import MergeInputs, MergePlan, plan_merge
from assurance.queue import ActionQueue, Segment
from tests.core.projection_oracle import violations

MS = 1_000_000
LIMITS = JointLimits.uniform(2, position=10.0, velocity=2.0, acceleration=1.0)


def chunk(actions: list[list[float]], dt_ms: float, first_ms: float) -> Chunk:
    result = decode_event_chunk({
        "chunk_id": "new", "sequence": 2, "queue_epoch": 1, "policy_checkpoint": "ck",
        "config_hash": "cfg", "skill_version": "1", "task_phase": "FREE_SPACE",
        "controller_mode": "position", "calibration_epoch": 1, "observation_id": "o",
        "first_action_time": first_ms, "action_dt": dt_ms, "actions": actions,
        "replacement_policy": "replace",
    }, client_receive=0)
    assert isinstance(result, Chunk)
    return result


def plan(queue: ActionQueue, new: Chunk, *, hold_q: np.ndarray | None,
         measured_q: np.ndarray) -> MergePlan:
    timing = Timing((), new.time("first_action_time"), 0, new.horizon, 10**15, 0)
    inputs = MergeInputs(new, timing, 0, 1, True, hold_q, measured_q)
    return plan_merge(queue, inputs, LIMITS)


def moving_queue(dt_ms: int, step: float, rows: int) -> ActionQueue:
    """Rows on a ``dt_ms`` grid moving ``step`` per row: the arm is cruising at step/dt."""
    values = np.array([[step * (i + 1)] * 2 for i in range(rows)])
    queue = ActionQueue()
    queue.push(Segment("old", 1, "FREE_SPACE", 0, 10**15, 0, dt_ms * MS, values, 0,
                       values[0] - step))
    return queue


def test_a_chunk_on_a_longer_interval_keeps_the_arms_velocity_through_the_change() -> None:
    # queued: 10 ms rows at 0.01 rad each (1 rad/s), the last (0.10) due at 90 ms
    queue = moving_queue(10, 0.01, 10)
    # the next chunk runs on 20 ms rows at the same 1 rad/s: 0.12, 0.14, ...
    new = chunk([[0.10 + 0.02 * (i + 1)] * 2 for i in range(5)], dt_ms=20, first_ms=100)
    result = plan(queue, new, hold_q=None, measured_q=np.zeros(2))
    # the reference step is the queued step on the new grid: 0.02 per 20 ms, not 0.01
    np.testing.assert_allclose(result.segment.step_into(0), [0.02, 0.02])
    assert result.projection.max_distance < 1e-9  # nothing to correct: no acceleration
    # and, whatever it was projected from, it is admissible from where the arm really is
    cruising = (np.full(2, 0.10), np.full(2, 0.02))
    assert not violations(result.segment.actions, *cruising, 0.02, LIMITS)


def test_a_chunk_on_a_shorter_interval_keeps_the_arms_velocity_through_the_change() -> None:
    queue = moving_queue(20, 0.02, 5)  # 1 rad/s on 20 ms rows, the last (0.10) at 80 ms
    new = chunk([[0.10 + 0.01 * (i + 1)] * 2 for i in range(6)], dt_ms=10, first_ms=100)
    result = plan(queue, new, hold_q=None, measured_q=np.zeros(2))
    cruising = (np.full(2, 0.10), np.full(2, 0.01))
    assert not violations(result.segment.actions, *cruising, 0.01, LIMITS)
    assert result.projection.max_distance < 1e-9


def test_a_measured_state_outside_the_limits_is_clipped_before_projecting_from_it() -> None:
    # nothing queued, not holding: the reference is the measured state, which lies 0.5 rad
    # beyond both position limits
    measured = np.array([10.5, -10.5])
    new = chunk([[9.0, -9.0]] * 4, dt_ms=10, first_ms=0)
    result = plan(ActionQueue(), new, hold_q=None, measured_q=measured)
    np.testing.assert_array_equal(result.segment.ref_q, [10.0, -10.0])
    at_the_limit = (np.array([10.0, -10.0]), np.zeros(2))
    assert not violations(result.segment.actions, *at_the_limit, 0.01, LIMITS)
