"""Admission gates (docs/contract.md §3–§4): content, identity, context, time, state divergence.

Every gate is a pure function of the chunk and an :class:`AdmissionContext` snapshot and returns
the reason codes that apply; the caller evaluates all of them and lists every reason, so a
refusal explains itself completely (the stale chunk of ``seed_stale_chunk.json`` is
``PHASE_MISMATCH + STATE_DIVERGED``, not merely late). Feasibility is the last gate and lives
with the merge, since it must run on the sequence that would actually be queued.
"""

from __future__ import annotations

import msgspec
import numpy as np

from assurance.clock import ClockInvalid, ClockMap, expires_at, rows_due_before, too_old
from assurance.envelope import Chunk
from assurance.handshake import AllowList, Session
from assurance.identity import Seen
from assurance.limits import JointLimits
from assurance.policy import PhasePolicy
from assurance.reasons import ReasonCode as R


class AdmissionContext(msgspec.Struct, frozen=True, eq=False):
    """What the client knows at the instant a chunk is admitted (built once per chunk)."""

    t: int
    session: Session | None
    allowlist: AllowList
    skill: str
    skill_version: str
    phase: str
    controller_mode: str
    calibration_epoch: str
    action_dim: int
    action_units: str
    action_frame: str
    queue_epoch: int
    last_sequence: int | None
    accepts_proposals: bool
    policy: PhasePolicy
    clock: ClockMap
    limits: JointLimits
    measured_q: np.ndarray


def content_reasons(chunk: Chunk, ctx: AdmissionContext) -> list[R]:
    reasons = []
    if chunk.nonfinite:
        reasons.append(R.NONFINITE)
    width = chunk.actions.shape[1]
    units_differ = chunk.action_units is not None and chunk.action_units != ctx.action_units
    frame_differs = chunk.action_frame is not None and chunk.action_frame != ctx.action_frame
    if width != ctx.action_dim or units_differ or frame_differs:
        reasons.append(R.SCHEMA_MISMATCH)
    return reasons


def identity_reasons(
    chunk: Chunk, seen: Seen, ctx: AdmissionContext, observed: bool
) -> list[R]:
    reasons = []
    if seen is Seen.CONFLICT:
        reasons.append(R.ID_CONFLICT)
    if chunk.queue_epoch < ctx.queue_epoch:
        reasons.append(R.OLD_QUEUE_EPOCH)
    elif chunk.queue_epoch > ctx.queue_epoch:
        reasons.append(R.FUTURE_QUEUE_EPOCH)
    elif ctx.last_sequence is not None and chunk.sequence <= ctx.last_sequence:
        reasons.append(R.REORDERED)
    if not observed:
        reasons.append(R.UNKNOWN_OBSERVATION)
    return reasons


def context_reasons(chunk: Chunk, ctx: AdmissionContext) -> list[R]:
    reasons = []
    session = ctx.session
    if session is None:
        reasons.append(R.HANDSHAKE_REQUIRED)
    checkpoint = session.policy_checkpoint if session else chunk.policy_checkpoint
    config = session.config_hash if session else chunk.config_hash
    if chunk.policy_checkpoint != checkpoint or (chunk.policy_checkpoint, config) not in (
        ctx.allowlist
    ):
        reasons.append(R.CHECKPOINT_NOT_ALLOWED)
    if chunk.config_hash != config:
        reasons.append(R.CONFIG_MISMATCH)
    skill_differs = chunk.skill is not None and chunk.skill != ctx.skill
    if skill_differs or chunk.skill_version != ctx.skill_version:
        reasons.append(R.SKILL_MISMATCH)
    if chunk.task_phase != ctx.phase:
        reasons.append(R.PHASE_MISMATCH)
    if chunk.controller_mode != ctx.controller_mode:
        reasons.append(R.CONTROLLER_MODE_MISMATCH)
    if chunk.calibration_epoch != ctx.calibration_epoch:
        reasons.append(R.CALIBRATION_MISMATCH)
    if not ctx.accepts_proposals:
        reasons.append(R.NO_AUTHORITY)
    return reasons


class Timing(msgspec.Struct, frozen=True):
    """The chunk's schedule on the client's clock, and what the time gates found."""

    reasons: tuple[R, ...]
    first_due: int | None = None
    """Due time of action 0 on the client's clock (None when it cannot be known)."""
    late: int = 0
    """Actions whose deadline passed before the chunk was ready (negative slack)."""
    runnable_until: int = 0
    """Index of the first action already too old at its own due time."""
    expires_at: int = 0
    """Client time from which any action of this chunk is too old to run
    (:func:`assurance.clock.expires_at`; a row is dropped once :func:`~assurance.clock.too_old`)."""
    trim: int = 0


def time_verdict(chunk: Chunk, ctx: AdmissionContext, t_obs: int | None) -> Timing:
    """Clock provenance, observation staleness, expiry and trimming (docs/contract.md §2)."""
    try:
        offset, uncertainty = ctx.clock.translator(chunk.clock_domain)
    except ClockInvalid:
        return Timing((R.CLOCK_INVALID,))
    times = chunk.times
    first, dt = times["first_action_time"], times["action_dt"]
    if t_obs is None or first is None or dt is None:
        return Timing(())  # unknown observation or non-finite schedule: refused elsewhere
    reasons: list[R] = []
    policy = ctx.policy
    max_obs_age = _stricter(policy.max_observation_age_ns, times["max_observation_age"])
    started = times["inference_start"]
    stale_from = expires_at(t_obs, max_obs_age, uncertainty)  # the same rule as for actions
    if started is not None and too_old(started + offset, stale_from):
        reasons.append(R.OBSERVATION_STALE)
    max_age = _stricter(policy.max_action_age_ns, times["max_action_age"])
    first_due = first + offset
    horizon = chunk.actions.shape[0]
    late = rows_due_before(first_due, dt, ctx.t, horizon)  # t_ready is the arrival instant
    expiry = expires_at(t_obs, max_age, uncertainty)
    runnable_until = rows_due_before(first_due, dt, expiry, horizon)
    trim = 0
    if late >= runnable_until:
        reasons.append(R.EXPIRED)
    elif late > 0:
        # The first rtc_delay actions of a conditioned chunk are the committed prefix, which
        # is running: dropping them trims nothing of the policy's own plan (assurance/rtc.py
        # checks that they are that prefix), not even a gripper event it already carries.
        committed = chunk.rtc_delay is not None and late <= chunk.rtc_delay
        if not (policy.trim or committed):
            reasons.append(R.EXPIRED)
        elif _trim_deletes_event(chunk, late, ctx.limits, gripper=not committed):
            reasons.append(R.TRIM_FORBIDDEN)
        else:
            trim = late
    return Timing(tuple(reasons), first_due, late, runnable_until, expiry, trim)


def _stricter(phase_bound: int, proposer_bound: int | None) -> int:
    return phase_bound if proposer_bound is None else min(phase_bound, proposer_bound)


def _trim_deletes_event(chunk: Chunk, late: int, limits: JointLimits,
                        gripper: bool = True) -> bool:
    """True if dropping actions ``0..late-1`` would delete a phase marker or (``gripper``) a
    gripper event."""
    if any(marker < late for marker in chunk.phase_markers):
        return True
    grip = limits.gripper_index
    if not gripper or grip is None or late < 2 or grip >= chunk.actions.shape[1]:
        return False
    prefix = chunk.actions[:late, grip]
    return bool(np.any(np.abs(np.diff(prefix)) > limits.gripper_event_threshold))


def divergence(chunk: Chunk, ctx: AdmissionContext, first_due: int | None) -> float:
    """Max-abs joint difference between the measured state and the action scheduled for now.

    The action scheduled for the admission instant is used, or the first action if the chunk
    starts later; the gripper dimension is left out.
    """
    actions, measured, grip = chunk.actions, ctx.measured_q, ctx.limits.gripper_index
    dt = chunk.times["action_dt"]
    index = 0
    if first_due is not None and dt is not None and ctx.t > first_due:
        index = min(actions.shape[0] - 1, (ctx.t - first_due) // dt)
    dim = ctx.limits.lower.shape[0]
    if actions.shape[1] != dim or measured.shape != (dim,):
        return 0.0
    # A handful of joints: plain floats cost less than three numpy calls here.
    gaps = [abs(a - m) for a, m in zip(actions[index].tolist(), measured.tolist(), strict=True)]
    if grip is not None:
        gaps[grip] = 0.0  # not a joint: a gripper event is a step, never a divergence
    return max(gaps)


def divergence_verdict(
    chunk: Chunk, ctx: AdmissionContext, first_due: int | None
) -> tuple[float | None, list[R]]:
    """The measured divergence (None when a non-finite or mis-sized chunk has none) and the
    reason it raises, if any."""
    if chunk.nonfinite or chunk.actions.shape[1] != ctx.action_dim:
        return None, []
    drift = divergence(chunk, ctx, first_due)
    return drift, ([R.STATE_DIVERGED] if drift > ctx.policy.max_divergence else [])


def divergence_reasons(chunk: Chunk, ctx: AdmissionContext, first_due: int | None) -> list[R]:
    return divergence_verdict(chunk, ctx, first_due)[1]
