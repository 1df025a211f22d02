"""Who owns motion: handlers for every event that is not a chunk or a tick.

Link, handshake, operator, controller, phase, force and OOD events all end here. Each one either
raises a fallback trigger (the table in :mod:`assurance.fallback` decides whether it applies),
asks the task FSM for a transition (evidence decides), or performs a recovery whose precondition
is checked and logged.
"""

from __future__ import annotations

import numpy as np

from assurance.clock import ClockSync
from assurance.fallback import Mode, QueueAction
from assurance.handshake import evaluate
from assurance.plausibility import judge
from assurance.reasons import ReasonCode as R
from kernel.core.descent import request_descent
from kernel.core.effects import Motion, Retreat, Setpoint
from kernel.core.events import (
    ClockSyncEvent,
    ControllerEvent,
    ControllerStatus,
    ForceEvent,
    GripperEvent,
    HandshakeEvent,
    InsertEvent,
    LinkEvent,
    LinkStatus,
    MoveEvent,
    ObservationEvent,
    OodEvent,
    OperatorAction,
    OperatorEvent,
    PhaseEvent,
    RecorderEvent,
    StateEvent,
)
from kernel.core.lines import (
    HandshakeLine,
    Machine,
    MotionDecision,
    MotionLine,
    MotionRequest,
)
from kernel.core.motion import request_move
from kernel.core.motion_state import MotionContext
from kernel.core.state import CoreState
from skills.contact import Descent, NoKinematics
from skills.phases import TaskPhase
from skills.task_fsm import Requester

_POSITION_TOLERANCE = 1e-6


def on_state(state: CoreState, event: StateEvent) -> None:
    q = np.asarray(event.q, dtype=float)
    if not np.isfinite(q).all():
        # Invalid feedback: keep the last valid measurement, stop trusting the controller.
        state.controller_ok = False
        state.fire(R.CONTROLLER_FAULT)
        return
    if q.shape[0] < state.measured_q.shape[0]:  # a state without the gripper keeps its last value
        q = np.concatenate([q, state.measured_q[q.shape[0]:]])
    # The device answered: the state watchdog (silence) is fed even by a sample that is not
    # believed; an implausible one is a fault of its own and never becomes the measurement.
    state.measured_t = state.t
    if _plausible(state, q, event.qd):
        state.measured_q = q
    if event.force_residual is not None:
        state.motion.force = event.force_residual
        _check_force(state, event.force_residual)
    _check_envelope(state, event.force_residual)


def _plausible(state: CoreState, q: np.ndarray, reported: tuple[float, ...] | None) -> bool:
    """Judge the sample's arm joints (:mod:`assurance.plausibility`); an implausible one is
    STATE_IMPLAUSIBLE: SAFE_HOLD where the arm was last plausibly measured."""
    limits, bounds = state.config.limits, state.plausibility
    if bounds is None or q.shape[0] != limits.dim:
        return True  # unreachable: the state is built with its bounds; shapes are the loader's
    arm = limits.arm_mask
    verdict = judge(state.plausible, state.t, q[arm], _arm_velocity(reported, arm), bounds)
    state.plausible = verdict.track
    if verdict.finding is None:
        return True
    state.fire(R.STATE_IMPLAUSIBLE, detail=verdict.finding.describe())
    return False


def _arm_velocity(reported: tuple[float, ...] | None, arm: np.ndarray) -> np.ndarray | None:
    """The reported velocities of the arm's joints, if the sample has them (with or without
    the gripper's); otherwise None: a driver that reports none is judged on positions."""
    if not reported:
        return None
    qd = np.asarray(reported, dtype=float)
    if qd.shape[0] == arm.shape[0]:
        qd = qd[arm]
    elif qd.shape[0] != int(arm.sum()):
        return None
    return qd


def _check_envelope(state: CoreState, force: float | None) -> None:
    """A trial's envelope, on what was measured: the tool in the box, the force below its
    limit. A breach stops the arm (ENVELOPE)."""
    bounds = state.config.envelope
    if bounds is None:
        return
    too_hard = force is not None and not abs(force) <= bounds.max_force_n
    if too_hard or not _tool_inside(state, state.measured_q[state.config.limits.arm_mask]):
        state.fire(R.ENVELOPE)


def outside_envelope(state: CoreState, motion: Motion) -> bool:
    """Would this motion effect command the tool out of the trial's box?"""
    if state.config.envelope is None or not isinstance(motion, Setpoint | Retreat):
        return False
    return not _tool_inside(state, np.asarray(motion.q))


def _tool_inside(state: CoreState, q: np.ndarray) -> bool:
    bounds, kinematics = state.config.envelope, state.config.kinematics
    if bounds is None or kinematics is None:  # the loader requires the model with a box
        return True
    return bounds.workspace.contains(kinematics.forward(q).position)


def on_observation(state: CoreState, event: ObservationEvent) -> None:
    """The observation is as old as the oldest thing it shows: its oldest frame, or the joint
    reading of the instant it was sent."""
    taken = min([state.t, *(frame.t_capture for frame in event.frames)])
    state.observations.record(event.observation_id, taken, event.rtc, state.queue_version)


def on_force(state: CoreState, event: ForceEvent) -> None:
    state.motion.force = event.residual
    _check_force(state, event.residual)


def _check_force(state: CoreState, residual: float) -> None:
    band = state.card.policy.force_band
    if band is not None and not band.contains(residual):
        state.fire(R.CONTACT_ANOMALY)


def on_ood(state: CoreState, event: OodEvent) -> None:
    threshold = state.card.policy.ood_threshold
    if threshold is not None and event.score > threshold:
        state.fire(R.OOD)


def on_clock_sync(state: CoreState, event: ClockSyncEvent) -> None:
    state.clock = state.clock.with_sync(ClockSync(event.domain, event.offset, event.round_trip))


def on_phase(state: CoreState, event: PhaseEvent) -> None:
    target, by = event.to, event.by
    fsm_authority = state.fallback.mode in (Mode.RUNNING, Mode.DEGRADED)
    before = state.task.phase
    decision = state.task.request(target, event.evidence, by, fsm_authority)
    state.log_task(decision)
    # A hold request holds the arm even when the task cannot mirror it (an aborted task).
    if target is TaskPhase.SAFE_HOLD and state.fire(R.HOLD_REQUESTED):
        return  # the fallback transition purged the queue already
    if not decision.accepted:
        return
    if before != state.task.phase:
        state.purge(decision.trigger)  # actions proposed for the old phase never run in the new
        state.hold_q = None


def on_link(state: CoreState, event: LinkEvent) -> None:
    if event.status == LinkStatus.UP:
        state.link_up = True
        return
    if not state.link_up and state.session is None:
        return
    state.link_up = False
    state.session = None
    state.observations.clear()
    if not state.fire(R.LINK_LOST):
        state.new_epoch(R.LINK_LOST)  # already in fallback: the session still ends here


def on_handshake(state: CoreState, event: HandshakeEvent) -> None:
    hello = state.config.client.hello(state.epoch)
    decision, session = evaluate(hello, event.offer, state.config.allowlist)
    replaced_a_session = state.session is not None
    state.link_up = True
    state.emit(HandshakeLine(
        t=state.t_ms, decision=decision.decision, fingerprint=decision.fingerprint,
        reasons=decision.reasons, protocol=decision.protocol, queue_epoch=state.epoch,
    ))
    state.decided(decision)
    state.session = session
    if session is None:
        _rejected(state, decision.reasons)
        return
    if state.fallback.mode is Mode.DEGRADED:
        state.log_task(state.task.begin_validation(R.HANDSHAKE_ACCEPTED))
        validate(state)
    elif state.fallback.mode is Mode.RUNNING and replaced_a_session:
        state.new_epoch(R.HANDSHAKE_ACCEPTED)  # a second session is a reconnection: new epoch


def _rejected(state: CoreState, reasons: tuple[str, ...]) -> None:
    """A rejected handshake ends the session at once: no debounce, whatever its reasons."""
    first = R(reasons[0]) if reasons else R.HANDSHAKE_REQUIRED
    if not state.fire(first, immediate=True):
        state.purge(first)  # "REJECT ... with an empty queue"


def validate(state: CoreState) -> None:
    """VALIDATE: the measured state is finite and inside the limits; then resume the phase."""
    if state.task.phase is not TaskPhase.VALIDATE:
        return
    limits = state.config.limits
    q = state.measured_q
    inside = np.all(q >= limits.lower - _POSITION_TOLERANCE) and np.all(
        q <= limits.upper + _POSITION_TOLERANCE)
    if not (np.isfinite(q).all() and inside):
        return
    if state.fallback.mode is Mode.DEGRADED and state.session is None:
        return
    state.log_task(state.task.finish_validation())
    transition = state.fallback.validated()
    if transition is not None:
        state.apply(transition)


def on_operator(state: CoreState, event: OperatorEvent) -> None:
    handler = _OPERATOR[event.action]
    handler(state)


def _takeover(state: CoreState) -> None:
    if not state.fire(R.HUMAN_TAKEOVER):
        state.refuse(Machine.FALLBACK, Mode.HUMAN_RECOVERY, R.NO_AUTHORITY,
                     f"takeover not possible in {state.fallback.mode}")


def _release(state: CoreState) -> None:
    _outcome(state, state.fallback.release(), Mode.SAFE_HOLD)


def _reset(state: CoreState) -> None:
    _outcome(state, state.fallback.reset(estop_clear=not state.estop_asserted), Mode.SAFE_HOLD)


def _accept_recovery(state: CoreState) -> None:
    outcome = state.fallback.recover(state.session is not None, state.controller_ok)
    if isinstance(outcome, str):
        state.refuse(Machine.FALLBACK, Mode.RUNNING, R.GUARD_FAILED, outcome)
        return
    state.apply(outcome, QueueAction.NEW_EPOCH)
    # Every way back to work passes VALIDATE, whichever fallback state it recovers from; an
    # idle or aborted task validates when it starts again.
    if state.task.phase not in (TaskPhase.IDLE, TaskPhase.ABORT):
        state.log_task(state.task.begin_validation(R.RECOVERY_ACCEPTED))
        validate(state)


def _estop(state: CoreState) -> None:
    state.fire(R.E_STOP)


def _abort(state: CoreState) -> None:
    state.log_task(state.task.request(TaskPhase.ABORT, {}, Requester.OPERATOR))


def _outcome(state: CoreState, outcome: object, target: Mode) -> None:
    if isinstance(outcome, str):
        state.refuse(Machine.FALLBACK, target, R.GUARD_FAILED, outcome)
        return
    state.apply(outcome)  # type: ignore[arg-type]


_OPERATOR = {
    OperatorAction.TAKEOVER: _takeover,
    OperatorAction.RELEASE: _release,
    OperatorAction.RESET: _reset,
    OperatorAction.ACCEPT_RECOVERY: _accept_recovery,
    OperatorAction.ESTOP: _estop,
    OperatorAction.ABORT: _abort,
}


def on_controller(state: CoreState, event: ControllerEvent) -> None:
    """The device's answer: a refused command or a fault stops the arm (CONTROLLER_STOP), an
    e-stop is E_STOP; ``ok`` is the precondition for recovering from either."""
    status = event.status
    if status == ControllerStatus.OK:
        state.controller_ok = True
        state.estop_asserted = False
        return
    if status == ControllerStatus.ESTOP:
        state.estop_asserted = True
        state.fire(R.E_STOP)
        return
    state.controller_ok = False
    trigger = R.CONTROLLER_REJECT if status == ControllerStatus.REJECT else R.CONTROLLER_FAULT
    state.fire(trigger)


def on_recorder(state: CoreState, event: RecorderEvent) -> None:
    """The run's record can no longer be written: stop the arm (RECORDER_FAILED →
    CONTROLLER_STOP); the shell ends the run after the tick that carries the stop. In
    CONTROLLER_STOP or E_STOP the arm is stopped already, and the line says so."""
    detail = f"the run's record cannot be written: {event.fault}"
    if not state.fire(R.RECORDER_FAILED, detail=detail):
        state.refuse(Machine.FALLBACK, Mode.CONTROLLER_STOP, R.RECORDER_FAILED,
                     f"{detail}; {state.fallback.mode} already stops the arm")


# -- the task's motion requests ------------------------------------------------------------------


def on_move(state: CoreState, event: MoveEvent) -> None:
    """A classical move: checked here, planned when the planner takes it up (a ``motion``
    line says which)."""
    target = np.asarray(event.target, dtype=float)
    limits = state.motion.planner_limits
    problem = ""
    if target.shape != (limits.dof,):
        problem = f"target has {target.shape[0]} values, the arm has {limits.dof} joints"
    elif not (np.isfinite(target).all() and limits.contains(target)):
        problem = "target is not finite or not inside the position limits"
    if problem:
        state.emit(MotionLine(t=state.t_ms, request=MotionRequest.MOVE,
                              decision=MotionDecision.REFUSED, move_id=event.move_id,
                              detail=problem))
        return
    request_move(state.motion, event.move_id, target)


def on_gripper(state: CoreState, event: GripperEvent) -> None:
    if not np.isfinite(event.opening) or event.opening < 0:
        state.emit(MotionLine(t=state.t_ms, request=MotionRequest.GRIPPER,
                              decision=MotionDecision.REFUSED,
                              detail=f"opening {event.opening!r} is not a distance"))
        return
    state.motion.gripper = event.opening
    state.emit(MotionLine(t=state.t_ms, request=MotionRequest.GRIPPER,
                          decision=MotionDecision.SET,
                          opening=event.opening))


def on_insert(state: CoreState, event: InsertEvent) -> None:
    """The contact owner's descent, from where the arm is measured now; with the cell's
    geometry, once its path is cleared (:func:`~kernel.core.descent.request_descent`). Not in
    a fallback mode: the contact owner is then not the one the task asks (a retreat, a hold,
    a human or a stop has the arm)."""
    rotation = np.asarray(event.rotation, dtype=float)
    values = np.array([*event.xy, event.z_end], dtype=float)
    detail = ""
    if rotation.shape != (9,) or not (np.isfinite(rotation).all() and np.isfinite(values).all()):
        detail = "xy, z_end and a 3x3 rotation must be finite numbers"
    elif state.fallback.mode is not Mode.RUNNING:
        detail = f"the contact owner is not the task's to ask in {state.fallback.mode}"
    else:
        limits = state.config.limits
        descent = Descent(limits.clip(state.measured_q)[limits.arm_mask], values[:2],
                          float(values[2]), rotation.reshape(3, 3))
        context = MotionContext(state.config, state.t, state.measured_q, state.emit,
                                str(state.task.phase), state.ask)
        try:
            if not request_descent(state.motion, context, descent):
                return  # checked first: a motion line says whether it started
        except (NoKinematics, ValueError) as error:
            detail = str(error)
    decision = MotionDecision.REFUSED if detail else MotionDecision.STARTED
    state.emit(MotionLine(t=state.t_ms, request=MotionRequest.INSERT, decision=decision,
                          detail=detail or None))
