"""Admission: every gate, then the merge, then one decision line (docs/contract.md §3–§4).

Order of work for one chunk: decode result → duplicate check (a duplicate is ignored and changes
nothing) → does a new chunk answer a pending observation (one already answered by an admitted
chunk is refused at once, ``OBSERVATION_ANSWERED``, with no other work) → content, identity,
context, time and divergence gates → merge plan and projection (feasibility) → decision. Only
an admitted chunk touches the queue, and it does so by one commit of a plan built beforehand.

Two steps may be long (:mod:`kernel.core.jobs`): mapping a Cartesian chunk to joint targets and
the exact projection of a proposal that fails the fast check. For those the chunk is parked and
a job is asked for; when its result comes back (:func:`on_computed`) the whole evaluation runs
again at that instant with the result in hand, so a chunk is always judged against the state
and the clock of the moment it is decided. A chunk that the cheap gates refuse already is
decided at once, without any long work.
"""

from __future__ import annotations

from dataclasses import dataclass

import msgspec
import numpy as np

from assurance.cartesian import Mapped
from assurance.clock import ns_to_ms
from assurance.envelope import Chunk, MalformedChunk
from assurance.fallback import IRRELEVANT, Mode
from assurance.gates import (
    AdmissionContext,
    Timing,
    content_reasons,
    context_reasons,
    divergence_verdict,
    identity_reasons,
    time_verdict,
)
from assurance.identity import Seen
from assurance.merge import MergeDraft, MergeInputs, MergePlan, draft_merge
from assurance.projection import Projection, project, project_fast
from assurance.reasons import ReasonCode as R
from assurance.reasons import canonical
from assurance.rtc import rtc_reasons
from kernel.core.clearance import clearance_job, collision_line
from kernel.core.descent import descent_checked
from kernel.core.effects import Compute
from kernel.core.jobs import (
    ClearanceJob,
    ClearanceResult,
    Job,
    JobFailed,
    JobResult,
    MapJob,
    MapResult,
    ProjectJob,
    ProjectResult,
    array_of,
    rows_of,
    run_job,
)
from kernel.core.lines import ChunkLine, Decision
from kernel.core.motion import move_checked
from kernel.core.motion_state import NOT_CHECKED
from kernel.core.retreat import retreat_checked
from kernel.core.state import CoreState
from kernel.core.verdict import answered_unusably, commit, log_decision, refuse

_PROJECTION_DIGITS = 9
_MAX_PROJECTION_JOBS = 2
"""A chunk whose merge changed while its projection ran is projected again once more in a job;
after that, inline (rare: the queue changed under it twice)."""


@dataclass(slots=True, eq=False)
class Parked:
    """A chunk waiting for a job's result."""

    chunk: Chunk
    seen: Seen
    job: Job
    mapped: Mapped | None = None
    projection_jobs: int = 0
    projected: tuple[ProjectJob, ProjectResult] | None = None
    checked: tuple[ClearanceJob, ClearanceResult] | None = None
    clearance_jobs: int = 0


def admit(state: CoreState, chunk: Chunk | MalformedChunk) -> None:
    if isinstance(chunk, MalformedChunk):
        refuse(state, chunk.chunk_id, (R.MALFORMED,), detail=chunk.detail)
        return
    seen = state.memory.classify(chunk.chunk_id, chunk.payload_hash)
    if seen is Seen.DUPLICATE:
        _ignore_duplicate(state, chunk)
        return
    if seen is Seen.NEW and state.observations.answered(chunk.observation_id):
        # Not remembered either: a flood of second answers must not push real chunks out of
        # the duplicate memory. (A reused chunk id is worse news: ID_CONFLICT, every gate.)
        refuse(state, chunk.chunk_id, (R.OBSERVATION_ANSWERED,))
        return
    state.memory.remember(chunk.chunk_id, chunk.payload_hash)
    if state.config.cartesian is not None and _worth_mapping(state, chunk, seen):
        _park(state, Parked(chunk, seen, MapJob(
            job_id=state.next_job_id(), actions=rows_of(chunk.actions),
            anchor=tuple(_anchor(state, chunk).tolist()))))
        return
    _evaluate(state, chunk, seen, None)


def on_computed(state: CoreState, result: JobResult) -> None:
    """A job's result: finish the parked chunk's admission with it (or clear or refuse the
    planned move it was asked for)."""
    if result.job_id == state.motion.move_check:
        move_checked(state.motion, _clearance_or_refusal(result), state.t, state.emit)
        return
    if result.job_id == state.motion.retreat_check:
        retreat_checked(state.motion, _clearance_or_refusal(result), state.t, state.emit)
        return
    if result.job_id == state.motion.descent_check:
        descent_checked(state.motion, _clearance_or_refusal(result), state.t, state.emit,
                        str(state.task.phase), state.fallback.mode is Mode.RUNNING)
        return
    parked = state.parked.pop(result.job_id, None)
    if parked is None:
        return  # not asked for by this core (a journal edited by hand): nothing to finish
    chunk = parked.chunk
    if isinstance(result, JobFailed):
        refuse(state, chunk.chunk_id, (R.INFEASIBLE,), detail=f"not checked: {result.detail}")
    elif isinstance(result, MapResult):
        parked.mapped = _mapped(result, chunk, state)
        _evaluate(state, chunk, parked.seen, parked)
    elif isinstance(result, ProjectResult) and isinstance(parked.job, ProjectJob):
        parked.projected = (parked.job, result)
        _evaluate(state, chunk, parked.seen, parked)
    elif isinstance(result, ClearanceResult) and isinstance(parked.job, ClearanceJob):
        parked.checked = (parked.job, result)
        _evaluate(state, chunk, parked.seen, parked)
    else:  # a result of another kind than the job asked for (a journal edited by hand)
        refuse(state, chunk.chunk_id, (R.INFEASIBLE,), detail="not checked: wrong result")


def _clearance_or_refusal(result: JobResult) -> ClearanceResult:
    """A motion's clearance result; a check that could not run refuses it: no motion is played
    unchecked."""
    if isinstance(result, ClearanceResult):
        return result
    return ClearanceResult(job_id=result.job_id, clear=False, pair=NOT_CHECKED)


def _ignore_duplicate(state: CoreState, chunk: Chunk) -> None:
    """A duplicate was decided already: ignore it, and say only what identifies it."""
    reasons = [R.DUPLICATE]
    if chunk.queue_epoch < state.epoch:
        reasons.append(R.OLD_QUEUE_EPOCH)
    elif chunk.queue_epoch > state.epoch:
        reasons.append(R.FUTURE_QUEUE_EPOCH)
    log_decision(state, ChunkLine(
        t=state.t_ms, chunk_id=chunk.chunk_id, decision=Decision.IGNORED,
        reasons=canonical(reasons), queue_epoch=state.epoch,
        queue_depth=state.queue.pending_rows(state.t),
    ))


def _worth_mapping(state: CoreState, chunk: Chunk, seen: Seen) -> bool:
    """Map a Cartesian chunk only if the cheap gates leave it a chance of being planned."""
    ctx = state.context()
    t_obs = state.observations.time_of(chunk.observation_id)
    reasons = content_reasons(chunk, ctx)
    reasons += identity_reasons(chunk, seen, ctx, observed=t_obs is not None)
    reasons += context_reasons(chunk, ctx)
    reasons += time_verdict(chunk, ctx, t_obs).reasons
    return _NOT_PLANNED.isdisjoint(reasons)


def _evaluate(state: CoreState, chunk: Chunk, seen: Seen, parked: Parked | None) -> None:
    ctx = state.context()
    t_obs = state.observations.time_of(chunk.observation_id)
    reasons = content_reasons(chunk, ctx)
    reasons += identity_reasons(chunk, seen, ctx, observed=t_obs is not None)
    reasons += context_reasons(chunk, ctx)
    timing = time_verdict(chunk, ctx, t_obs)
    reasons += timing.reasons
    sent = state.observations.prefix_of(chunk.observation_id)
    rtc, rtc_problem = rtc_reasons(
        chunk, None if sent is None else sent[0], t_obs, timing.first_due, timing.late,
        ctx.policy.max_projection, state.config.limits,
        changed=sent is not None and sent[1] != state.queue_version)
    reasons += rtc
    mapped = parked.mapped if parked is not None else None
    joints, unmappable = _in_joint_space(state, chunk, reasons, mapped)
    drift, plan = None, None
    if joints is None:
        reasons += [R.INFEASIBLE] if unmappable else []
    else:
        joint_ctx = ctx if joints is chunk else _joint_context(ctx, joints)
        drift, diverged = divergence_verdict(joints, joint_ctx, timing.first_due)
        reasons += diverged
        if _can_plan(joints, timing, reasons):
            inputs = _inputs(state, joints, timing, t_obs)
            draft = draft_merge(state.queue, inputs, state.config.limits)
            projection = _projection(state, draft, parked)
            if projection is None:
                _park(state, _projecting(state, chunk, seen, parked, draft))
                return
            plan = draft.finish(projection, inputs)
    collision = None
    if plan is not None:
        reasons += _feasibility_reasons(state, plan)
        if not reasons and state.config.collision is not None:
            job = clearance_job(state, plan)
            collision = _clearance(state, job, parked)
            if collision is None:
                _park(state, _checking(state, chunk, seen, parked, job))
                return
            reasons += [] if collision.clear else [R.COLLISION]
    extras = _measurements(state, t_obs, plan, drift)
    if collision is not None and not collision.clear:
        extras["collision"] = collision_line(collision)
    if unmappable or rtc_problem:
        extras["detail"] = unmappable or rtc_problem
    if reasons:
        refuse(state, chunk.chunk_id, canonical(reasons), **extras)
        answered_unusably(state, chunk, reasons)
        return
    commit(state, chunk, plan, t_obs, extras)


def _projection(state: CoreState, draft: MergeDraft, parked: Parked | None) -> Projection | None:
    """The draft's projection: the fast check's, the job's (if it was for these very rows
    and reference), or None when a job must compute it."""
    limits, dt_s = state.config.limits, draft.dt * 1e-9
    fast = project_fast(draft.rows, draft.reference, dt_s, limits)
    if fast is not None:
        return fast
    if parked is not None and parked.projected is not None and _same_inputs(
            parked.projected[0], draft):
        exact = parked.projected[1]
        width = limits.dim
        actions = array_of(exact.actions, width)
        return Projection(actions, np.array(exact.distances), exact.recoverable,
                          exact.max_distance)
    if parked is not None and parked.projection_jobs >= _MAX_PROJECTION_JOBS:
        return project(draft.rows, draft.reference, dt_s, limits)
    return None


def _same_inputs(job: ProjectJob, draft: MergeDraft) -> bool:
    return job.dt_ns == draft.dt and (
        job.rows == rows_of(draft.rows)) and job.ref_q == tuple(draft.reference.q.tolist()) and (
        job.ref_step == tuple(draft.reference.step.tolist()))


def _projecting(state: CoreState, chunk: Chunk, seen: Seen, parked: Parked | None,
                draft: MergeDraft) -> Parked:
    job = ProjectJob(job_id=state.next_job_id(), rows=rows_of(draft.rows),
                     ref_q=tuple(draft.reference.q.tolist()),
                     ref_step=tuple(draft.reference.step.tolist()), dt_ns=draft.dt)
    if parked is None:
        return Parked(chunk, seen, job, projection_jobs=1)
    parked.job = job
    parked.projection_jobs += 1
    return parked


def _clearance(state: CoreState, job: ClearanceJob,
               parked: Parked | None) -> ClearanceResult | None:
    """The check's result if a job computed it for these very rows (else None: a job must),
    or computed here after the queue changed under two jobs already (rare)."""
    if parked is not None and parked.checked is not None:
        asked, result = parked.checked
        if msgspec.structs.replace(asked, job_id=0) == job:
            return result
    if parked is not None and parked.clearance_jobs >= _MAX_PROJECTION_JOBS:
        found = run_job(job, state.config.limits, None, state.config.collision)
        return found if isinstance(found, ClearanceResult) else None
    return None


def _checking(state: CoreState, chunk: Chunk, seen: Seen, parked: Parked | None,
              job: ClearanceJob) -> Parked:
    job = msgspec.structs.replace(job, job_id=state.next_job_id())
    if parked is None:
        parked = Parked(chunk, seen, job)
    parked.job = job
    parked.clearance_jobs += 1
    return parked


def _park(state: CoreState, parked: Parked) -> None:
    state.parked[parked.job.job_id] = parked
    state.effect(Compute(job=parked.job))


def _mapped(result: MapResult, chunk: Chunk, state: CoreState) -> Mapped:
    if result.joints is None:
        return Mapped(None, result.detail)
    return Mapped(array_of(result.joints, state.config.limits.dim))


def _in_joint_space(state: CoreState, chunk: Chunk, reasons: list[R],
                    mapped: Mapped | None) -> tuple[Chunk | None, str]:
    """The chunk with joint-space actions, or None and (if it cannot be mapped) why.

    A joint-space session's chunk is itself. A Cartesian chunk's mapping (a job's result) was
    made from the state the policy observed; one that is non-finite or of the wrong schema is
    not mapped (its refusal already says why), one that leaves the workspace or has no IK
    solution is INFEASIBLE as a whole.
    """
    if state.config.cartesian is None:
        return chunk, ""
    if R.NONFINITE in reasons or R.SCHEMA_MISMATCH in reasons or mapped is None:
        return None, ""
    if mapped.joints is None:
        return None, mapped.detail
    return msgspec.structs.replace(chunk, actions=mapped.joints), ""


def _anchor(state: CoreState, chunk: Chunk) -> np.ndarray:
    """The joint state a Cartesian chunk is relative to: the one the policy saw, if it says."""
    measured = state.measured_q
    seen = chunk.fingerprint_q
    arm = state.config.limits.arm_mask
    if seen is None:
        return measured
    if len(seen) == measured.shape[0]:
        return np.array(seen)
    if len(seen) == int(arm.sum()):
        anchor = measured.copy()
        anchor[arm] = seen
        return anchor
    return measured


def _joint_context(ctx: AdmissionContext, joints: Chunk) -> AdmissionContext:
    """Gates that read actions see joint targets: a mapped chunk is as wide as the robot (a
    joint-space chunk keeps its session's width, so a chunk of the wrong width stays one)."""
    width = joints.actions.shape[1]
    return ctx if width == ctx.action_dim else msgspec.structs.replace(ctx, action_dim=width)


_NOT_PLANNED = frozenset({R.NONFINITE, R.SCHEMA_MISMATCH, R.CLOCK_INVALID,
                          R.UNKNOWN_OBSERVATION, R.EXPIRED, R.TRIM_FORBIDDEN}) | IRRELEVANT


def _can_plan(chunk: Chunk, timing: Timing, reasons: list[R]) -> bool:
    """Feasibility is judged only for a chunk that could be merged into the current queue.

    It needs a finite chunk of the right width and a schedule whose late prefix could be
    trimmed; a chunk made for another phase, epoch, session or owner is not projected either,
    because a projection against a context it was not made for would mean nothing (its refusal
    already says why).
    """
    if not _NOT_PLANNED.isdisjoint(reasons) or timing.first_due is None:
        return False
    return timing.late < timing.runnable_until or chunk.horizon == 0


def _inputs(state: CoreState, chunk: Chunk, timing: Timing, t_obs: int | None) -> MergeInputs:
    period = state.config.control_period_ns
    return MergeInputs(
        chunk=chunk, timing=timing, t_obs=int(t_obs or 0), epoch=state.epoch,
        blend_allowed=state.card.policy.blend, hold_q=state.hold_q, measured_q=state.measured_q,
        last_setpoint=state.last_setpoint,
        next_tick=None if state.last_tick is None else state.last_tick + period,
        period=period,
    )


def _feasibility_reasons(state: CoreState, plan: MergePlan) -> list[R]:
    reasons = []
    projection = plan.projection
    if not projection.recoverable or projection.max_distance > state.card.policy.max_projection:
        reasons.append(R.INFEASIBLE)
    if plan.older_than_queue:
        reasons.append(R.REORDERED)
    return reasons


def _measurements(
    state: CoreState, t_obs: int | None, plan: MergePlan | None, drift: float | None
) -> dict[str, object]:
    extras: dict[str, object] = {}
    if t_obs is not None:
        extras["observation_age_ms"] = ns_to_ms(state.t - t_obs)
    if plan is not None:
        extras["projection_distance"] = round(plan.projection.max_distance, _PROJECTION_DIGITS)
    if drift is not None:
        extras["divergence"] = round(drift, _PROJECTION_DIGITS)
    return extras
