"""Real-time chunking's gate (assurance/rtc.py) and the prefix the queue gives, on hand-built
chunks; the whole path through the core is tests/scenarios (the rtc_* scenarios)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from assurance.clock import ClockMap
from assurance.envelope import Chunk
from assurance.event_chunk import decode_event_chunk
from assurance.gates import AdmissionContext, time_verdict
from assurance.handshake import Session
from assurance.limits import JointLimits
from assurance.policy import PhasePolicy
from assurance.queue import ActionQueue, Segment
from assurance.reasons import ReasonCode as R
from assurance.rtc import RtcPrefix, committed_prefix, rtc_reasons
from kernel.scenario.events import parse_events
from kernel.scenario.fields import ScenarioError, Where

MS = 1_000_000
DT = 10 * MS
T_OBS = 40 * MS
LIMITS = JointLimits.uniform(3, position=3.0, velocity=2.0, acceleration=20.0, gripper_index=2)
"""Two joints and a gripper (its event threshold: 1 mm)."""
BOUND = 0.01
PREFIX_ROWS = [[0.1 * k, -0.05 * k, 0.02] for k in range(8)]


def _prefix(rows: list[list[float]] | None = None, delay: int = 3) -> RtcPrefix:
    rows = PREFIX_ROWS if rows is None else rows
    return RtcPrefix(actions=tuple(map(tuple, rows)), first_due=T_OBS, action_dt=DT,
                     delay=delay, horizon=5)


def _chunk(actions: list[list[float]], delay: int | None = 3, first_ms: float = 40,
           dt_ms: float = 10, **fields: Any) -> Chunk:
    event: dict[str, Any] = {
        "chunk_id": "c2", "sequence": 2, "queue_epoch": 0, "policy_checkpoint": "ck",
        "config_hash": "cfg", "skill_version": "1", "task_phase": "PRE_CONTACT",
        "controller_mode": "position", "calibration_epoch": "cal", "observation_id": "o2",
        "first_action_time": first_ms, "action_dt": dt_ms, "actions": actions,
        "rtc_delay": delay, **fields,
    }
    chunk = decode_event_chunk({k: v for k, v in event.items() if v is not None}, 0)
    assert isinstance(chunk, Chunk), chunk
    return chunk


def _gate(chunk: Chunk, prefix: RtcPrefix | None = None, late: int = 2,
          first_due: int | None = T_OBS) -> list[R]:
    return rtc_reasons(chunk, prefix if prefix is not None else _prefix(), T_OBS, first_due,
                       late, BOUND, LIMITS)[0]


def _honouring(delay: int = 3, width: int = 12) -> list[list[float]]:
    plan = [[0.1 * k, -0.05 * k, 0.02] for k in range(delay, width)]
    return [*PREFIX_ROWS[:delay], *plan]


def test_a_chunk_that_says_nothing_of_rtc_passes_untouched() -> None:
    assert rtc_reasons(_chunk(_honouring(), delay=None), None, T_OBS, T_OBS, 9, BOUND,
                       LIMITS) == ([], None)


def test_a_chunk_that_reproduces_the_prefix_passes() -> None:
    assert _gate(_chunk(_honouring())) == []


@given(late=st.integers(0, 8), delay=st.integers(0, 8), off=st.floats(0.0, 0.05),
       grip=st.floats(0.0, 0.002), row=st.integers(0, 7))
def test_refused_exactly_when_the_seam_leaves_the_prefix_or_comes_too_late(
        late: int, delay: int, off: float, grip: float, row: int) -> None:
    """The oracle is the definition: the first ``delay`` arm values within the bound of the
    prefix and the gripper within its event threshold, and no more actions due than
    ``delay``."""
    actions = _honouring(delay=delay)
    actions[row] = [actions[row][0] + off, actions[row][1], actions[row][2] + grip]
    reasons = _gate(_chunk(actions, delay=delay), _prefix(delay=delay), late=late)
    moved = abs(actions[row][0] - PREFIX_ROWS[row][0]) if row < len(PREFIX_ROWS) else 0.0
    gripped = abs(actions[row][2] - PREFIX_ROWS[row][2]) if row < len(PREFIX_ROWS) else 0.0
    mismatch = row < delay and (moved > BOUND or gripped > LIMITS.gripper_event_threshold)
    if mismatch:
        assert reasons == [R.RTC_PREFIX_MISMATCH]
    elif late > delay:
        assert reasons == [R.RTC_DELAY_EXCEEDED]
    else:
        assert reasons == []


def test_each_way_of_not_matching_the_prefix_is_named() -> None:
    honest = _honouring()
    cases = {
        "carried no committed prefix": rtc_reasons(_chunk(honest), None, T_OBS, T_OBS, 2,
                                                   BOUND, LIMITS),
        "grid": rtc_reasons(_chunk(honest, dt_ms=20), _prefix(), T_OBS, T_OBS, 2, BOUND,
                            LIMITS),
        "not due when the prefix's first action was": rtc_reasons(
            _chunk(honest, first_ms=45), _prefix(), T_OBS, 45 * MS, 2, BOUND, LIMITS),
        "the prefix had 8": rtc_reasons(_chunk(honest, delay=9), _prefix(), T_OBS, T_OBS, 2,
                                        BOUND, LIMITS),
        "values per action": rtc_reasons(_chunk([[0.0, 0.0]] * 12), _prefix(), T_OBS, T_OBS,
                                         2, BOUND, LIMITS),
        "gripper differs": rtc_reasons(
            _chunk([[r[0], r[1], 0.04] for r in honest]), _prefix(), T_OBS, T_OBS, 2, BOUND,
            LIMITS),
        "the queue changed after its observation": rtc_reasons(
            _chunk(honest), _prefix(), T_OBS, T_OBS, 2, BOUND, LIMITS, changed=True),
    }
    for expected, (reasons, detail) in cases.items():
        assert reasons == [R.RTC_PREFIX_MISMATCH], expected
        assert detail is not None and expected in detail, (expected, detail)


def test_a_nan_in_the_conditioned_actions_never_agrees() -> None:
    actions = _honouring()
    actions[0] = [float("nan"), 0.0, 0.02]
    assert _gate(_chunk(actions)) == [R.RTC_PREFIX_MISMATCH]


def _segment(rows: np.ndarray, first_due: int, dt: int, chunk_id: str = "c1") -> Segment:
    return Segment(chunk_id=chunk_id, epoch=0, phase="PRE_CONTACT", t_obs=0,
                   expires_at=10**12, first_due=first_due, dt=dt, actions=rows,
                   first_index=0, ref_q=rows[0])


def test_the_prefix_starts_with_the_action_in_force_on_its_own_due_time() -> None:
    queue = ActionQueue()
    rows = np.arange(10, dtype=float)[:, None] * np.ones((1, 3))
    queue.push(_segment(rows, first_due=20 * MS, dt=10 * MS))
    # At 42 ms row 2 (due at 40) is in force: on the chunks' own grid, the rows themselves.
    committed = committed_prefix(queue, 42 * MS, 10 * MS)
    assert committed.first_due == 40 * MS
    assert committed.rows[:, 0].tolist() == list(range(2, 10))
    # On a 5 ms grid: the rows in force at 40, 45, ... 115 ms.
    finer = committed_prefix(queue, 42 * MS, 5 * MS)
    assert finer.rows[:, 0].tolist() == [2 + k // 2 for k in range(16)]
    assert committed_prefix(ActionQueue(), 0, DT).rows.shape[0] == 0


def test_the_prefix_follows_a_later_segment_from_its_first_due_time() -> None:
    queue = ActionQueue()
    queue.push(_segment(np.zeros((10, 3)), first_due=0, dt=DT))
    queue.push(_segment(np.ones((4, 3)), first_due=30 * MS, dt=DT, chunk_id="c2"))
    committed = committed_prefix(queue, 10 * MS, DT)
    assert committed.first_due == 10 * MS
    assert committed.rows[:, 0].tolist() == [0.0, 0.0, 1.0, 1.0, 1.0, 1.0]


def _timing(chunk: Chunk, t_ms: float) -> Any:
    """The time gates of a PRE_CONTACT card, which forbids trimming, at ``t_ms``."""
    ctx = AdmissionContext(
        t=round(t_ms * MS), session=Session("ck", "cfg", "fp", 1, 10),
        allowlist=frozenset({("ck", "cfg")}), skill="insert", skill_version="1",
        phase="PRE_CONTACT", controller_mode="position", calibration_epoch="cal",
        action_dim=3, action_units="rad", action_frame="joint", queue_epoch=0,
        last_sequence=None, accepts_proposals=True,
        policy=PhasePolicy(max_observation_age_ns=200 * MS, max_action_age_ns=300 * MS),
        clock=ClockMap(), limits=LIMITS, measured_q=np.zeros(3))
    return time_verdict(chunk, ctx, 0)


def test_only_the_committed_prefix_may_be_dropped_where_trimming_is_forbidden() -> None:
    """Due every 10 ms from 40 ms, conditioned on 3 actions: up to 3 may be due when it is
    admitted (dropped, trimmed); a fourth is the policy's own plan, and it is too late."""
    chunk = _chunk(_honouring())
    assert _timing(chunk, 65).trim == 3 and not _timing(chunk, 65).reasons
    assert _timing(chunk, 75).reasons == (R.EXPIRED,)
    unconditioned = _chunk(_honouring(), delay=None)
    assert _timing(unconditioned, 45).reasons == (R.EXPIRED,)


def test_a_phase_marker_among_the_committed_actions_still_forbids_dropping_them() -> None:
    marked = _chunk(_honouring(), phase_markers=[1])
    assert _timing(marked, 65).reasons == (R.TRIM_FORBIDDEN,)


@pytest.mark.parametrize(("rtc", "says"), [
    ({"actions": [5], "first_action_time_ns": 0, "action_dt_ns": DT, "delay": 1, "horizon": 1},
     "each a list of numbers"),
    ({"actions": [[0.0, 0.0, 0.0]] * 1025, "first_action_time_ns": 0, "action_dt_ns": DT,
      "delay": 1, "horizon": 1}, "at most 1024"),
    ({"actions": [[0.0] * 3], "first_action_time_ns": 0, "action_dt_ns": 0, "delay": 1,
      "horizon": 1}, "action_dt_ns"),
    ({"actions": [[0.0] * 3], "first_action_time_ns": 0, "action_dt_ns": DT, "delay": 2000,
      "horizon": 1}, "delay"),
])
def test_a_prefix_a_file_cannot_mean_is_named_never_raised(rtc: dict[str, Any],
                                                          says: str) -> None:
    record = {"t": 0, "kind": "observation", "observation_id": "o1", "rtc": rtc}
    with pytest.raises(ScenarioError, match=says):
        parse_events([record], Where("scenario.json", "events"), LIMITS)
