"""The control tick: who owns this period, and what goes out (docs/contract.md §4, §7).

Outside RUNNING the fallback state decides (hold, retreat, stop, human; in DEGRADED the phase's
classical owner keeps its job, and contact ends as the phase card's ``link_loss`` says). In
RUNNING the phase's executor decides: a policy phase sends the queued action in force, or holds
at the measured state on underrun (a validated hold, never the last action repeated) and
escalates to SAFE_HOLD if the underrun lasts; the contact owner runs the impedance law with the
admitted bounded target if there is one; the planner runs its classical trajectory. Every tick
that is not a policy setpoint carries its reason.
"""

from __future__ import annotations

import msgspec
import numpy as np

from assurance.clock import ns_to_ms
from assurance.fallback import MODES, FallbackCommand, Mode, Owner
from assurance.policy import LinkLoss
from assurance.queue import Row, SentRow
from assurance.reasons import ReasonCode as R
from kernel.core.authority import outside_envelope, validate
from kernel.core.cameras import cameras_seeing, check_cameras
from kernel.core.effects import Motion, RequestObservation
from kernel.core.lines import QueueAction, QueueLine, RequestLine, SentRef, TickLine
from kernel.core.motion import motion_for
from kernel.core.motion_state import MotionContext
from kernel.core.state import CoreState
from skills.phases import Executor, TaskPhase


class TickCommand(msgspec.Struct, frozen=True, eq=False):
    """Who owns this period and where it may go (``target``: a joint vector where one applies);
    :mod:`kernel.core.motion` turns it into the one motion effect of the tick."""

    command: FallbackCommand
    owner: Owner
    target: np.ndarray | None
    sent: SentRef | None
    reason: R | None
    t_obs: int | None = None
    relax: float | None = None
    """The contact owner stops pressing and holds at this fraction of its stiffness."""


def tick(state: CoreState) -> TickCommand:
    _stall(state)
    state.last_tick = state.t
    _watchdog(state)
    check_cameras(state)
    if state.task.phase is TaskPhase.VALIDATE:
        validate(state)
    row = _row_in_force(state) if state.fallback.mode is Mode.RUNNING else None
    decision = _decide(state, row)
    _track_hold(state, decision)
    motion = _motion(state, decision, row)
    if outside_envelope(state, motion):
        # The setpoint would take the tool out of the trial's box: it is never sent; the arm
        # stops now, and the tick is the fallback's.
        state.fire(R.ENVELOPE)
        row = None
        decision = _decide(state, row)
        _track_hold(state, decision)
        motion = _motion(state, decision, row)
    policy_setpoint = (decision.command is FallbackCommand.SETPOINT
                       and decision.owner is Owner.POLICY)
    state.last_setpoint = SentRow.of(row) if policy_setpoint and row is not None else None
    _log(state, decision)
    state.effect(motion)
    _maybe_request(state)
    return decision


def _motion(state: CoreState, decision: TickCommand, row: Row | None) -> Motion:
    """The tick's one motion effect: what reaches the arm."""
    sent = stream = None
    if decision.sent is not None:
        sent = (decision.sent.chunk_id, decision.sent.index)
    if row is not None and decision.owner is Owner.POLICY:
        stream = (row.segment.step_into(row.row), row.segment.dt)
    context = MotionContext(state.config, state.t, state.measured_q, state.emit,
                            str(state.task.phase), state.ask)
    return motion_for(state.motion, context, decision.command, decision.owner, decision.target,
                      sent, stream, decision.relax)


def _stall(state: CoreState) -> None:
    """A control loop that stalled past the state watchdog is a fault, not a quiet delay: for
    that long nothing was decided and no command went out, whatever the samples say now. The
    gap is between tick times, which the journal records, so a replay decides the same."""
    timeout = state.config.state_timeout_ns
    if timeout is None or state.last_tick is None:
        return
    gap = state.t - state.last_tick
    if gap > timeout:
        state.fire(R.WATCHDOG, detail=f"no control tick for {ns_to_ms(gap)} ms (state "
                   f"watchdog {ns_to_ms(timeout)} ms): the control loop stalled")


def _watchdog(state: CoreState) -> None:
    timeout = state.config.state_timeout_ns
    if timeout is None:
        return
    if state.watched_since is None:
        state.watched_since = state.t  # from the first tick: a state that never comes is caught
    last = state.measured_t if state.measured_t is not None else state.watched_since
    if state.t - last > timeout:
        state.fire(R.WATCHDOG)


def _row_in_force(state: CoreState) -> Row | None:
    """The queued row due now that is still young enough; expired rows are dropped, logged.

    A segment's expiry instant already includes the clock uncertainty (gates.time_verdict).
    """
    while True:
        row = state.queue.active(state.t)
        if row is None or not row.segment.too_old(state.t):
            return row
        dropped = state.queue.unrun_rows(state.t)
        chunk_id, _ = state.queue.drop_head()
        state.emit(QueueLine(t=state.t_ms, action=QueueAction.EXPIRE, queue_epoch=state.epoch,
                             dropped=dropped, chunk_id=chunk_id, reason=R.EXPIRED))


def _decide(state: CoreState, row: Row | None) -> TickCommand:
    mode = state.fallback.mode
    if mode is Mode.RUNNING:
        return _running(state, row)
    if mode is Mode.DEGRADED:
        return _degraded(state)
    card = MODES[mode]
    holds = card.command is FallbackCommand.HOLD and card.owner is not Owner.HUMAN
    target = _hold(state) if holds else None
    return TickCommand(card.command, card.owner, target, None, state.fallback.cause)


def _running(state: CoreState, row: Row | None) -> TickCommand:
    executor = state.card.executor
    if executor is Executor.POLICY:
        return _policy(state, row)
    if executor is Executor.CONTACT:
        return _contact(state, row)
    if executor is Executor.PLANNER:
        command = (FallbackCommand.RETREAT if state.task.phase is TaskPhase.RETREAT
                   else FallbackCommand.SETPOINT)
        return TickCommand(command, Owner.PLANNER, None, None, R.PHASE_OWNER)
    owner = Owner.FALLBACK if state.task.phase is TaskPhase.VALIDATE else Owner.PLANNER
    return TickCommand(FallbackCommand.HOLD, owner, _hold(state), None, R.PHASE_OWNER)


def _policy(state: CoreState, row: Row | None) -> TickCommand:
    if row is not None:
        state.executed_in_epoch = True
        state.underrun_since = None
        sent = SentRef(row.segment.chunk_id, row.chunk_index)
        return TickCommand(FallbackCommand.SETPOINT, Owner.POLICY, row.q, sent, None,
                           row.segment.t_obs)
    if _underrun_escalates(state):
        return _decide(state, None)
    return TickCommand(FallbackCommand.HOLD, Owner.FALLBACK, _hold(state), None, R.UNDERRUN)


def _underrun_escalates(state: CoreState) -> bool:
    """An underrun after the queue has run in this epoch escalates once it lasts too long."""
    if not state.executed_in_epoch:
        return False
    if state.underrun_since is None:
        state.underrun_since = state.t
    if state.t - state.underrun_since < state.card.policy.underrun_limit_ns:
        return False
    return state.fire(R.UNDERRUN)


def _contact(state: CoreState, row: Row | None) -> TickCommand:
    if row is not None:
        sent = SentRef(row.segment.chunk_id, row.chunk_index)
        return TickCommand(FallbackCommand.CONTACT, Owner.CONTACT, row.q, sent, R.PHASE_OWNER,
                           row.segment.t_obs)
    return TickCommand(FallbackCommand.CONTACT, Owner.CONTACT, _hold(state), None, R.UNDERRUN)


def _degraded(state: CoreState) -> TickCommand:
    """Without the policy link the phase's classical owner keeps its job and policy phases
    hold; a contact phase ends contact as its card says (``link_loss``): the contact owner
    retracts, or stops pressing and holds softly where it is."""
    cause = state.fallback.cause
    executor = state.card.executor
    if executor is Executor.CONTACT:
        policy = state.card.policy
        if policy.link_loss is LinkLoss.RETRACT:
            return TickCommand(FallbackCommand.RETREAT, Owner.CONTACT, None, None, cause)
        return TickCommand(FallbackCommand.CONTACT, Owner.CONTACT, _hold(state), None, cause,
                           relax=policy.link_loss_hold_factor)
    if executor is Executor.PLANNER:
        command = (FallbackCommand.RETREAT if state.task.phase is TaskPhase.RETREAT
                   else FallbackCommand.SETPOINT)
        return TickCommand(command, Owner.PLANNER, None, None, cause)
    return TickCommand(FallbackCommand.HOLD, Owner.FALLBACK, _hold(state), None, cause)


def _hold(state: CoreState) -> np.ndarray:
    """The validated hold target: latched at the measured state when the hold begins."""
    if state.hold_q is None:
        state.hold_q = state.hold_target()
    return state.hold_q


def _track_hold(state: CoreState, decision: TickCommand) -> None:
    """A tick that does not hold ends the hold: the next hold latches a fresh target."""
    if decision.target is not state.hold_q:
        state.hold_q = None


def _log(state: CoreState, decision: TickCommand) -> None:
    age = ns_to_ms(state.t - decision.t_obs) if decision.t_obs is not None else None
    state.emit(TickLine(
        t=state.t_ms, command=decision.command, owner=decision.owner, sent=decision.sent,
        phase=state.task.phase, mode=state.fallback.mode, reason=decision.reason, age_ms=age,
    ))


def _maybe_request(state: CoreState) -> None:
    marks = state.watermarks
    if marks is None:
        return
    allowed = (state.accepts_proposals and state.link_up and state.session is not None
               and cameras_seeing(state))
    depth = state.queue.depth_ns(state.t)
    if marks.should_request(state.t, depth, allowed):
        rows = state.queue.pending_rows(state.t)
        state.emit(RequestLine(
            t=state.t_ms, observation_id=state.observations.latest, queue_depth=rows,
            depth_ms=ns_to_ms(depth), low_watermark_ms=ns_to_ms(marks.low_ns),
        ))
        state.effect(RequestObservation(queue_depth=rows))
