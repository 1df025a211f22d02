"""Turning an admissible chunk into queued rows: trim, replace, append or blend, then project.

The merge is planned on copies and only committed by the caller, so a chunk that fails its last
gate leaves the queue exactly as it was. Feasibility always runs on the sequence that would be
queued — after trimming, after replacement (the new first row follows a different predecessor)
and after blending (the mean of two feasible actions need not be feasible).
"""

from __future__ import annotations

import msgspec
import numpy as np

from assurance.envelope import Chunk, ReplacementPolicy
from assurance.gates import Timing
from assurance.limits import JointLimits
from assurance.projection import Projection, Reference, project
from assurance.queue import ActionQueue, Row, Segment, SentRow


class MergePlan(msgspec.Struct, frozen=True, eq=False):
    segment: Segment
    merge: ReplacementPolicy
    cut_at: int | None
    """Rows due at or after this time are swapped out when the plan is committed."""
    displaced: int
    """Rows of earlier chunks that the swap removes."""
    blended: bool
    projection: Projection
    older_than_queue: bool
    """The chunk would displace rows conditioned on a newer observation."""
    trimmed: int
    """Late actions dropped from the front of the chunk."""

    def commit(self, queue: ActionQueue) -> None:
        if self.cut_at is not None:
            queue.cut_from(self.cut_at)
        if self.segment.rows:
            queue.push(self.segment)


class MergeInputs(msgspec.Struct, frozen=True, eq=False):
    chunk: Chunk
    timing: Timing
    t_obs: int
    epoch: int
    blend_allowed: bool
    hold_q: np.ndarray | None
    """Where the robot is being held, if it is; else it starts from ``measured_q`` (clipped
    into the limits) when no queued row precedes the chunk."""
    measured_q: np.ndarray
    last_setpoint: SentRow | None = None
    """The row the last tick sent, if it sent one: precedes the chunk when the queue has no
    row before it any more (purged by a new epoch), so the new rows continue its motion."""
    next_tick: int | None = None
    """When the next control tick is due, and ``period`` the control period: the rows that
    precede the chunk are the ones ticks will actually send. A queued row whose whole window
    falls between two ticks is never sent, so the chunk must not follow it. None: no tick
    has run yet (every queued row is taken as sent)."""
    period: int = 0


class MergeDraft(msgspec.Struct, frozen=True, eq=False):
    """A merge worked out up to its feasibility projection: the rows that would be queued and
    the setpoint they follow. Projecting ``rows`` from ``reference`` and :meth:`finish` make
    the plan (the projection may run elsewhere: it is a pure function of these two)."""

    rows: np.ndarray
    reference: Reference
    first_due: int
    dt: int
    merge: ReplacementPolicy
    cut_at: int | None
    displaced: int
    blended: bool
    older_than_queue: bool
    first_index: int

    def finish(self, projection: Projection, inputs: MergeInputs) -> MergePlan:
        segment = _segment(inputs, projection, self.reference, self.first_due, self.dt,
                           self.first_index)
        return MergePlan(segment, self.merge, self.cut_at, self.displaced, self.blended,
                         projection, self.older_than_queue, inputs.timing.trim)


def draft_merge(queue: ActionQueue, inputs: MergeInputs, limits: JointLimits) -> MergeDraft:
    chunk, timing = inputs.chunk, inputs.timing
    dt = chunk.times["action_dt"] or 1
    first_due = int(timing.first_due or 0) + timing.trim * dt
    rows = chunk.actions[timing.trim:]
    policy = chunk.replacement_policy
    if policy is ReplacementPolicy.BLEND and not inputs.blend_allowed:
        policy = ReplacementPolicy.REPLACE
    cut_at: int | None = first_due
    skip, blended, older = 0, False, False
    if policy is ReplacementPolicy.APPEND:
        cut_at = None
        end = queue.last_end()
        if end is not None and end > first_due:
            skip = min(rows.shape[0], -(-(end - first_due) // dt))
    else:
        newest = queue.obs_time_from(first_due)
        older = newest is not None and newest > inputs.t_obs
        if policy is ReplacementPolicy.BLEND:
            rows, blended = _blend(queue, rows, first_due, dt)
    rows, first_due = rows[skip:], first_due + skip * dt
    displaced = queue.rows_from(cut_at) if cut_at is not None else 0
    reference = _reference(queue, first_due, dt, inputs, cut_at, limits)
    return MergeDraft(rows, reference, first_due, dt, policy, cut_at, displaced, blended, older,
                      timing.trim + skip)


def plan_merge(queue: ActionQueue, inputs: MergeInputs, limits: JointLimits) -> MergePlan:
    """The whole merge, its projection included."""
    draft = draft_merge(queue, inputs, limits)
    return draft.finish(project(draft.rows, draft.reference, draft.dt * 1e-9, limits), inputs)


def _blend(
    queue: ActionQueue, rows: np.ndarray, first_due: int, dt: int
) -> tuple[np.ndarray, bool]:
    """Cross-fade from the queued rows to the new ones over their overlap."""
    old = [queue.value_at(first_due + j * dt) for j in range(rows.shape[0])]
    overlap = [j for j, value in enumerate(old) if value is not None]
    if not overlap:
        return rows, False
    mixed = rows.copy()
    for rank, j in enumerate(overlap, start=1):
        weight = rank / (len(overlap) + 1)
        mixed[j] = (1.0 - weight) * old[j] + weight * rows[j]
    return mixed, True


def _reference(
    queue: ActionQueue, first_due: int, dt: int, inputs: MergeInputs, cut_at: int | None,
    limits: JointLimits,
) -> Reference:
    """The setpoint the first new row follows.

    The queued row before it, moving, if the two are contiguous. After a gap the queue runs dry
    first and the robot comes to rest where that row left it, so the reference is that row at
    rest. With nothing queued before it, it is the setpoint the last tick sent (the queue was
    purged under a moving arm), contiguous, or else the current hold (or the measured state).
    """
    queued = _last_sent_before(queue, first_due if cut_at is None else min(first_due, cut_at),
                               inputs)
    before = SentRow.of(queued) if queued is not None else None
    last = inputs.last_setpoint
    if before is None and last is not None and _contiguous(last, first_due, dt):
        before = last
    if before is None:
        start = inputs.hold_q if inputs.hold_q is not None else limits.clip(inputs.measured_q)
        return Reference(start, np.zeros_like(start))
    if not _contiguous(before, first_due, dt):
        return Reference(before.q, np.zeros_like(before.q))
    step = before.step
    return Reference(before.q, step if before.dt == dt else step * (dt / before.dt))


def _last_sent_before(queue: ActionQueue, anchor: int, inputs: MergeInputs) -> Row | None:
    """The queued row the last tick before ``anchor`` will send (None: that tick is the next
    one, or has run: the row it sent is ``inputs.last_setpoint``)."""
    first_tick = inputs.next_tick
    if first_tick is None or inputs.period <= 0:
        return queue.predecessor(anchor)
    if anchor <= first_tick:
        return None
    t_ref = first_tick + (anchor - 1 - first_tick) // inputs.period * inputs.period
    return queue.row_in_force(t_ref) or queue.predecessor(anchor)


def _contiguous(before: SentRow, first_due: int, dt: int) -> bool:
    due = before.due
    return due + before.dt >= first_due and due >= first_due - 2 * dt


def _segment(
    inputs: MergeInputs, projection: Projection, reference: Reference, first_due: int, dt: int,
    first_index: int,
) -> Segment:
    return Segment(
        chunk_id=inputs.chunk.chunk_id, epoch=inputs.epoch, phase=inputs.chunk.task_phase,
        t_obs=inputs.t_obs, expires_at=inputs.timing.expires_at, first_due=first_due, dt=dt,
        actions=projection.actions, first_index=first_index, ref_q=reference.q,
    )
