"""Admission gates: content, identity, context, time and divergence, on hand-built chunks."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from assurance.clock import ClockMap, ClockSync
from assurance.envelope import Chunk
from assurance.event_chunk import decode_event_chunk
from assurance.gates import (
    AdmissionContext,
    content_reasons,
    context_reasons,
    divergence,
    divergence_reasons,
    identity_reasons,
    time_verdict,
)
from assurance.handshake import Session
from assurance.identity import Seen
from assurance.limits import JointLimits
from assurance.policy import PhasePolicy
from assurance.reasons import ReasonCode as R

MS = 1_000_000
LIMITS = JointLimits.uniform(3, position=3.0, velocity=2.0, acceleration=20.0, gripper_index=2)
SESSION = Session("ck", "cfg", "fp", 1, 10)


def chunk(**changes: Any) -> Chunk:
    """Actions due every 10 ms from 100 ms; observation sensed at 0 ms."""
    ev = {
        "chunk_id": "c1", "sequence": 5, "queue_epoch": 2, "policy_checkpoint": "ck",
        "config_hash": "cfg", "skill": "insert", "skill_version": "1", "task_phase": "PRE_CONTACT",
        "controller_mode": "position", "calibration_epoch": "cal", "observation_id": "o1",
        "inference_start": 20, "first_action_time": 100, "action_dt": 10,
        "actions": [[0.1 * i, 0.0, 0.0] for i in range(10)],
    }
    ev.update(changes)
    result = decode_event_chunk({k: v for k, v in ev.items() if v is not None}, 0)
    assert isinstance(result, Chunk), result
    return result


def context(**changes: Any) -> AdmissionContext:
    policy = {"max_observation_age_ns": 50 * MS, "max_action_age_ns": 200 * MS,
              "max_divergence": 0.05, **changes.pop("policy", {})}
    base: dict[str, Any] = dict(
        t=100 * MS, session=SESSION, allowlist=frozenset({("ck", "cfg")}), skill="insert",
        skill_version="1", phase="PRE_CONTACT", controller_mode="position",
        calibration_epoch="cal", action_dim=3, action_units="rad", action_frame="joint",
        queue_epoch=2, last_sequence=4, accepts_proposals=True,
        policy=PhasePolicy(**policy),
        clock=ClockMap(), limits=LIMITS, measured_q=np.zeros(3),
    )
    base.update(changes)
    return AdmissionContext(**base)


def at(t_ms: float, **changes: Any) -> AdmissionContext:
    return context(t=int(t_ms * MS), **changes)


# --- content, identity, context ----------------------------------------------------------------


def test_a_matching_chunk_passes_every_gate() -> None:
    c, ctx = chunk(), context()
    assert content_reasons(c, ctx) == []
    assert identity_reasons(c, Seen.NEW, ctx, observed=True) == []
    assert context_reasons(c, ctx) == []
    assert time_verdict(c, ctx, t_obs=0).reasons == ()
    assert divergence_reasons(c, ctx, 100 * MS) == []


@pytest.mark.parametrize(("changes", "ctx"), [
    ({"actions": [[0.0, 0.0]]}, {}), ({"action_units": "deg"}, {}), ({"action_frame": "tool"}, {}),
    ({}, {"action_dim": 4}),
])
def test_schema_mismatch(changes: dict, ctx: dict) -> None:
    assert content_reasons(chunk(**changes), context(**ctx)) == [R.SCHEMA_MISMATCH]


def test_nonfinite_is_reported_with_content() -> None:
    assert content_reasons(chunk(inference_start=float("nan")), context()) == [R.NONFINITE]


@pytest.mark.parametrize(("seen", "changes", "ctx", "observed", "expected"), [
    (Seen.CONFLICT, {}, {}, True, [R.ID_CONFLICT]),
    (Seen.NEW, {"queue_epoch": 1, "sequence": 1}, {}, True, [R.OLD_QUEUE_EPOCH]),
    (Seen.NEW, {"queue_epoch": 3}, {}, True, [R.FUTURE_QUEUE_EPOCH]),
    (Seen.NEW, {"sequence": 4}, {}, True, [R.REORDERED]),
    (Seen.NEW, {"sequence": 0}, {"last_sequence": None}, True, []),
    (Seen.NEW, {}, {}, False, [R.UNKNOWN_OBSERVATION]),
])
def test_identity_reasons(seen: Seen, changes: dict, ctx: dict, observed: bool,
                          expected: list[R]) -> None:
    assert identity_reasons(chunk(**changes), seen, context(**ctx), observed) == expected


@pytest.mark.parametrize(("changes", "ctx", "expected"), [
    ({"policy_checkpoint": "ck-old"}, {}, [R.CHECKPOINT_NOT_ALLOWED]),
    ({"config_hash": "cfg2"}, {}, [R.CONFIG_MISMATCH]),
    ({"policy_checkpoint": "ck2", "config_hash": "cfg2"}, {"allowlist": frozenset(
        {("ck", "cfg"), ("ck2", "cfg2")})}, [R.CHECKPOINT_NOT_ALLOWED, R.CONFIG_MISMATCH]),
    ({}, {"allowlist": frozenset()}, [R.CHECKPOINT_NOT_ALLOWED]),
    ({"skill": "peg"}, {}, [R.SKILL_MISMATCH]),
    ({"skill_version": "2"}, {}, [R.SKILL_MISMATCH]),
    ({"task_phase": "FREE_SPACE"}, {}, [R.PHASE_MISMATCH]),
    ({"controller_mode": "torque"}, {}, [R.CONTROLLER_MODE_MISMATCH]),
    ({"calibration_epoch": "cal-old"}, {}, [R.CALIBRATION_MISMATCH]),
    ({}, {"accepts_proposals": False}, [R.NO_AUTHORITY]),
    ({}, {"session": None}, [R.HANDSHAKE_REQUIRED]),
])
def test_context_reasons(changes: dict, ctx: dict, expected: list[R]) -> None:
    assert context_reasons(chunk(**changes), context(**ctx)) == expected


def test_context_lists_every_reason_that_applies() -> None:
    reasons = context_reasons(chunk(task_phase="FREE_SPACE", controller_mode="torque"),
                              context(accepts_proposals=False))
    assert reasons == [R.PHASE_MISMATCH, R.CONTROLLER_MODE_MISMATCH, R.NO_AUTHORITY]


# --- time --------------------------------------------------------------------------------------


def test_on_time_chunk_has_no_late_prefix() -> None:
    timing = time_verdict(chunk(), at(100), t_obs=0)
    assert timing.first_due == 100 * MS and timing.late == 0 and timing.trim == 0
    assert timing.expires_at == 200 * MS + 1
    assert timing.runnable_until == 10


@pytest.mark.parametrize(("t_ms", "late"), [(100, 0), (100.000001, 1), (110, 1), (125, 3),
                                            (500, 10)])
def test_late_prefix_counts_actions_whose_deadline_passed(t_ms: float, late: int) -> None:
    assert time_verdict(chunk(), at(t_ms), t_obs=0).late == late


def test_runnable_until_is_the_first_action_too_old_at_its_due_time() -> None:
    # max action age 200 ms from t_obs=40 ms: due times 100..190 ms, too old after 240 ms
    assert time_verdict(chunk(), at(100), t_obs=40 * MS).runnable_until == 10
    assert time_verdict(chunk(), at(100), t_obs=-55 * MS).runnable_until == 5
    assert time_verdict(chunk(max_action_age=120), at(100), t_obs=0).runnable_until == 3


def test_a_chunk_with_no_runnable_action_is_expired() -> None:
    timing = time_verdict(chunk(inference_start=None), at(100), t_obs=-200 * MS)
    assert timing.reasons == (R.EXPIRED,) and timing.trim == 0


def test_a_late_prefix_is_expired_when_the_phase_forbids_trimming() -> None:
    timing = time_verdict(chunk(), at(125), t_obs=0)
    assert timing.reasons == (R.EXPIRED,) and timing.late == 3 and timing.trim == 0


def test_a_late_prefix_is_trimmed_when_allowed() -> None:
    timing = time_verdict(chunk(), at(125, policy={"trim": True}), t_obs=0)
    assert timing.reasons == () and timing.trim == 3


def test_trim_forbidden_when_a_gripper_event_is_inside_the_prefix() -> None:
    actions = [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]] + [[0.0, 0.0, 1.0]] * 8
    timing = time_verdict(chunk(actions=actions), at(125, policy={"trim": True}), t_obs=0)
    assert timing.reasons == (R.TRIM_FORBIDDEN,) and timing.trim == 0
    # the event right after the prefix is kept, so trimming is fine
    later = [[0.0, 0.0, 0.0]] * 3 + [[0.0, 0.0, 1.0]] * 7
    assert time_verdict(chunk(actions=later), at(125, policy={"trim": True}), 0).trim == 3


def test_trim_forbidden_when_a_phase_marker_is_inside_the_prefix() -> None:
    ctx = at(125, policy={"trim": True})
    assert time_verdict(chunk(phase_markers=[2]), ctx, 0).reasons == (R.TRIM_FORBIDDEN,)
    assert time_verdict(chunk(phase_markers=[3]), ctx, 0).trim == 3


def test_observation_stale_accounts_for_clock_uncertainty() -> None:
    # inference started 50 ms after the observation: exactly at the bound
    assert time_verdict(chunk(inference_start=50), at(100), t_obs=0).reasons == ()
    uncertain = at(100, clock=ClockMap(base_uncertainty_ns=1))
    assert R.OBSERVATION_STALE in time_verdict(chunk(inference_start=50), uncertain, 0).reasons
    assert R.OBSERVATION_STALE in time_verdict(
        chunk(inference_start=50, max_observation_age=40), at(100), 0).reasons


def test_uncertainty_brings_expiry_earlier() -> None:
    plain = time_verdict(chunk(), at(100), t_obs=0)
    uncertain = time_verdict(chunk(), at(100, clock=ClockMap(base_uncertainty_ns=15 * MS)), 0)
    assert uncertain.expires_at == plain.expires_at - 15 * MS
    assert uncertain.runnable_until == 9


def test_a_foreign_clock_without_sync_is_clock_invalid() -> None:
    timing = time_verdict(chunk(clock_domain="server"), at(100), t_obs=0)
    assert timing.reasons == (R.CLOCK_INVALID,) and timing.first_due is None


def test_a_synced_foreign_clock_is_translated() -> None:
    clock = ClockMap().with_sync(ClockSync("server", offset_ns=-1000 * MS, round_trip_ns=4 * MS))
    c = chunk(clock_domain="server", first_action_time=1100, inference_start=1020)
    timing = time_verdict(c, at(100, clock=clock), t_obs=0)
    assert timing.first_due == 100 * MS and timing.reasons == ()
    assert timing.expires_at == 200 * MS - 2 * MS + 1


def fresh() -> Chunk:
    """The standard chunk without an inference start: staleness is not judged, only expiry."""
    return chunk(inference_start=None)


def test_a_long_tail_is_admitted_and_expires_at_the_instant_its_rows_become_too_old() -> None:
    """Observation 150 ms before the first action, 200 ms allowed: actions at 100..150 ms are
    young enough when due (150 ms exactly at the bound), the tail from 160 ms on is not. The
    chunk is admitted (the tail is dropped when due, by the queue), and its expiry instant is
    the bound to the nanosecond."""
    timing = time_verdict(fresh(), at(100), t_obs=-50 * MS)
    assert timing.reasons == () and timing.late == 0
    assert timing.runnable_until == 6
    assert timing.expires_at == 150 * MS + 1  # age 200 ms at 150 ms may run; 1 ns later not
    clocked = at(100, clock=ClockMap(base_uncertainty_ns=1))
    assert time_verdict(fresh(), clocked, t_obs=-50 * MS).runnable_until == 5  # 150 ms: too old
    assert time_verdict(fresh(), clocked, t_obs=-50 * MS + 1).runnable_until == 6


def test_an_observation_exactly_at_the_bound_still_runs_one_ns_older_is_expired() -> None:
    """The first action is due at 100 ms; 200 ms allowed."""
    on_the_bound = time_verdict(fresh(), at(100), t_obs=-100 * MS)
    assert on_the_bound.reasons == () and on_the_bound.runnable_until == 1
    older = time_verdict(fresh(), at(100), t_obs=-100 * MS - 1)
    assert older.reasons == (R.EXPIRED,) and older.runnable_until == 0


def test_a_synced_clock_brings_expiry_earlier_by_half_its_round_trip_and_the_base() -> None:
    clock = ClockMap(base_uncertainty_ns=3 * MS).with_sync(
        ClockSync("server", offset_ns=-1000 * MS, round_trip_ns=10 * MS))
    c = chunk(clock_domain="server", first_action_time=1100, inference_start=None)
    timing = time_verdict(c, at(100, clock=clock), t_obs=-50 * MS)
    assert timing.expires_at == 150 * MS - 8 * MS + 1
    assert timing.runnable_until == 5  # 140 ms is due before 142 ms + 1 ns, 150 ms is not


@pytest.mark.parametrize(("ready_ns", "late"), [(100 * MS - 1, 0), (100 * MS, 0),
                                                (100 * MS + 1, 1), (110 * MS, 1),
                                                (110 * MS + 1, 2)])
def test_negative_slack_at_the_nanosecond(ready_ns: int, late: int) -> None:
    """An action due exactly when the chunk is ready has zero slack: on time."""
    assert time_verdict(chunk(), context(t=ready_ns), t_obs=0).late == late


@given(st.integers(-400, 150), st.integers(0, 300), st.integers(1, 20), st.integers(0, 20),
       st.integers(20, 250), st.booleans())
def test_the_time_verdict_agrees_with_the_contract_action_by_action(
    obs_ms: int, ready_ms: int, dt_ms: int, uncertainty_ms: int, max_age_ms: int, trim: bool
) -> None:
    """Each action judged by the contract's own words at its due time: late when its slack is
    negative, too old when age + uncertainty > max age. EXPIRED exactly when no action is
    both; with trimming, a late prefix before runnable actions is trimmed."""
    c = chunk(action_dt=dt_ms, max_action_age=max_age_ms, inference_start=None)
    ctx = context(t=ready_ms * MS, clock=ClockMap(base_uncertainty_ns=uncertainty_ms * MS),
                  policy={"trim": trim})
    timing = time_verdict(c, ctx, t_obs=obs_ms * MS)
    due = [(100 + j * dt_ms) * MS for j in range(10)]
    late = [d - ready_ms * MS < 0 for d in due]
    bound = min(max_age_ms, 200) * MS  # the stricter of the chunk's and the phase's
    old = [d - obs_ms * MS + uncertainty_ms * MS > bound for d in due]
    runnable = [not a and not b for a, b in zip(late, old, strict=True)]
    assert timing.late == sum(late)
    assert timing.runnable_until == sum(1 for o in old if not o)
    assert (R.EXPIRED in timing.reasons) == (not any(runnable) or (any(late) and not trim))
    if R.EXPIRED not in timing.reasons:
        assert timing.trim == sum(late)
        assert all(runnable[timing.trim:timing.runnable_until])


def test_unknown_observation_or_schedule_gives_no_time_reasons() -> None:
    assert time_verdict(chunk(), at(100), t_obs=None) == time_verdict(
        chunk(first_action_time=float("nan")), at(100), 0)


# --- divergence --------------------------------------------------------------------------------


def test_divergence_uses_the_action_scheduled_for_the_admission_instant() -> None:
    c = chunk()  # joint 0 runs 0.0, 0.1, 0.2, ... every 10 ms from 100 ms
    ctx = at(125, measured_q=np.array([0.2, 0.0, 0.0]))
    assert divergence(c, ctx, 100 * MS) == 0.0
    assert divergence(c, at(125, measured_q=np.zeros(3)), 100 * MS) == pytest.approx(0.2)


def test_divergence_uses_the_first_action_if_the_chunk_starts_later() -> None:
    c = chunk(actions=[[0.3, 0.0, 0.0]] + [[0.9, 0.0, 0.0]] * 9)
    assert divergence(c, at(50), 100 * MS) == pytest.approx(0.3)


def test_divergence_uses_the_last_action_after_the_chunk_ended() -> None:
    assert divergence(chunk(), at(1000), 100 * MS) == pytest.approx(0.9)


def test_divergence_ignores_the_gripper() -> None:
    c = chunk(actions=[[0.0, 0.0, 5.0]] * 10)
    assert divergence(c, at(100), 100 * MS) == 0.0
    assert divergence_reasons(c, at(100), 100 * MS) == []


def test_state_diverged_above_the_phase_bound() -> None:
    c = chunk(actions=[[0.0, 0.06, 0.0]] * 10)
    assert divergence_reasons(c, at(100), 100 * MS) == [R.STATE_DIVERGED]
    loose = at(100, policy={"max_divergence": 0.1})
    assert divergence_reasons(c, loose, 100 * MS) == []


def test_divergence_is_skipped_for_nonfinite_or_misshapen_chunks() -> None:
    far = [[9.0, 9.0, 9.0]] * 10
    assert divergence_reasons(chunk(actions=far, inference_start=float("inf")), at(100),
                              100 * MS) == []
    assert divergence_reasons(chunk(actions=far), at(100, action_dim=4), 100 * MS) == []


def test_the_context_is_a_frozen_snapshot() -> None:
    with pytest.raises(AttributeError):
        context().t = 5  # type: ignore[misc]


@pytest.mark.parametrize(("closing", "forbidden"), [(0.004, True), (0.0015, True),
                                                    (0.0005, False)])
def test_a_small_gripper_closing_in_the_prefix_forbids_the_trim(closing: float,
                                                                forbidden: bool) -> None:
    """The default gripper-event threshold is 1 mm: a gripper closing by a few millimetres in
    one row is an event a trim must not delete; sensor-sized jitter below it is not (issue 15,
    item 14: a threshold ×10 let a trim delete a closing)."""
    assert LIMITS.gripper_event_threshold == 1e-3
    actions = [[0.0, 0.0, 0.05], [0.0, 0.0, 0.05 - closing]] + [[0.0, 0.0, 0.05 - closing]] * 8
    timing = time_verdict(chunk(actions=actions), at(125, policy={"trim": True}), t_obs=0)
    if forbidden:
        assert timing.reasons == (R.TRIM_FORBIDDEN,) and timing.trim == 0
    else:
        assert timing.reasons == () and timing.trim == 3
