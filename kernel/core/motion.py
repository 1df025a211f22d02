"""Motion inside the core: from a tick's decision to the one command that reaches the arm.

The tick decides who owns the period and where it may go (:mod:`kernel.core.tick`); this module
turns that into one motion effect with the right law, on the core's own control period:

- the setpoint interpolator (ruckig) for policy actions and holds, so every stream, every hold
  and every hand-over stays inside the velocity, acceleration and jerk limits;
- the planner's classical move (requested by a ``move`` event) while the planner owns the tick;
- the contact owner's impedance law (an ``insert`` event starts its descent) in contact: its
  compliance targets exactly as the law computes them, from where the arm is measured;
- the device's own stop, or its own hold when a human has the arm.

Hand-overs never jump. The interpolator restarts from the last commanded state (clipped into
the limits, so a measured overshoot cannot stop a stop). A planner move, new or interrupted by
another owner, starts only once the interpolator has brought the arm to rest where the last
owner left it, and is then planned rest-to-rest from there, instead of resuming mid-profile at
the speed it had when it was paused.

Pure: time is the core's, the period the core's config; nothing here reads a clock.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from assurance.clock import ns_to_ms
from assurance.fallback import FallbackCommand, Owner
from kernel.core.effects import Hold, Motion, Retreat, Setpoint, Stop
from kernel.core.jobs import ClearanceJob, ClearanceResult, rows_of
from kernel.core.lines import Line, MotionDecision, MotionLine, MotionRequest
from kernel.core.motion_state import MotionContext, MotionState, collision_detail
from kernel.core.retreat import drop_retreat, retreat
from skills.contact import ContactState
from skills.interpolator import InterpolatorConfig, SetpointInterpolator
from skills.planner import MoveStatus, PlannedMove, PlanningError, joint_move

RESUME_AT_REST_RAD_S = 1e-3
RESUME_AT_REST_RAD_S2 = 1e-2
RESUME_SETTLED_RAD = 1e-6
"""When the interpolator counts as settled, so a planner move may start from rest: this close
to its latched target, this slow, this little acceleration."""


def motion_for(m: MotionState, ctx: MotionContext, command: FallbackCommand, owner: Owner,
               target: np.ndarray | None, sent: tuple[str, int] | None,
               stream: tuple[np.ndarray, int] | None = None,
               relax: float | None = None) -> Motion:
    """The motion effect for one tick's decision (see the module docstring). ``stream``: for
    a queued action, its step from the action before and the action grid's interval.
    ``relax``: the contact owner stops pressing and holds at that fraction of its stiffness."""
    _start(m, ctx)
    if owner is not Owner.CONTACT or command is not FallbackCommand.RETREAT:
        drop_retreat(m, ctx.t, ctx.emit)
    planner_tick = owner is Owner.PLANNER and command in (FallbackCommand.SETPOINT,
                                                          FallbackCommand.RETREAT)
    resuming = planner_tick and not m.planner_had_tick
    m.planner_had_tick = planner_tick
    if command is FallbackCommand.STOP:
        _restart(m, ctx.measured)
        return Stop(gripper=m.gripper, owner=owner)
    if command is FallbackCommand.HOLD and owner is Owner.HUMAN:
        _restart(m, ctx.measured)
        return Hold(gripper=m.gripper, owner=owner)
    if owner is Owner.CONTACT:
        return _contact(m, ctx, command, target, sent is not None, relax)
    if planner_tick:
        return _planned(m, ctx, resuming, retreat=command is FallbackCommand.RETREAT)
    goal = ctx.measured if target is None else np.asarray(target)[ctx.arm]
    arm_stream = None if stream is None else (np.asarray(stream[0])[ctx.arm], stream[1])
    q = _interpolated(m, ctx, goal, arm_stream)
    gripper = _gripper_of(m, ctx, target)
    chunk_id, index = sent if sent is not None else (None, None)
    return Setpoint(q=q, gripper=gripper, owner=owner, chunk_id=chunk_id, index=index)


def request_move(m: MotionState, move_id: int, target: np.ndarray) -> None:
    """A classical move to ``target``: it waits for the planner's tick and for rest."""
    m.move, m.move_id, m.move_target = None, move_id, target
    m.move_status, m.move_detail = MoveStatus.WAITING, ""
    m.awaiting_rest = False
    m.move_check = None  # an earlier move's check answers for that move only: it is dropped


# -- laws --------------------------------------------------------------------------------------


def _start(m: MotionState, ctx: MotionContext) -> None:
    """The first tick starts from where the arm was measured (a device starts wherever it was
    parked), clipped into the limits."""
    if m.interpolator is not None:
        return
    limits = m.interpolator_limits
    config = InterpolatorConfig(control_period_ns=ctx.config.control_period_ns)
    m.interpolator = SetpointInterpolator(limits, _inside(m, ctx.measured), config)
    m.commanded = m.interpolator.setpoint.position.copy()


def _interpolated(m: MotionState, ctx: MotionContext, goal: np.ndarray,
                  stream: tuple[np.ndarray, int] | None = None) -> tuple[float, ...]:
    limits = m.interpolator_limits
    clipped = np.clip(goal, limits.lower, limits.upper)
    setpoint = _interpolator(m).update(clipped, ctx.t, stream)
    return _commanded(m, setpoint.position)


def _planned(m: MotionState, ctx: MotionContext, resuming: bool, retreat: bool) -> Motion:
    """The planner's tick: settle, plan from rest, then play the move one period per tick."""
    interpolator = _interpolator(m)
    wanted = m.move_status is MoveStatus.WAITING or (resuming and m.move is not None)
    if wanted and not m.awaiting_rest and (m.move_check is None or resuming):
        m.awaiting_rest = True
        m.rest_target = interpolator.setpoint.position.copy()
    if (m.awaiting_rest and not _plan_from_rest(m, ctx)) or m.move_check is not None:
        return _planner_effect(m, _interpolated(m, ctx, m.rest_target), retreat)
    if m.move is None:  # nothing to play (none asked, or refused): hold still
        return _planner_effect(m, _interpolated(m, ctx, _commanded_array(m)), retreat)
    sample = m.move.advance(ctx.config.control_period_ns * 1e-9)
    if m.move.finished:
        m.move_status = MoveStatus.FINISHED
    interpolator.reset(sample.position, sample.velocity, sample.acceleration)
    return _planner_effect(m, _commanded(m, sample.position), retreat)


def _plan_from_rest(m: MotionState, ctx: MotionContext) -> bool:
    """Plan the wanted move once the interpolator is settled; False: not settled yet.

    Settled means arrived at the latched target with velocity *and* acceleration about zero: a
    velocity crossing zero on an overshoot still carries full acceleration, and a rest-to-rest
    plan from there would be a jerk step.
    """
    setpoint = _interpolator(m).setpoint
    settled = (
        float(np.abs(setpoint.position - m.rest_target).max()) <= RESUME_SETTLED_RAD
        and float(np.abs(setpoint.velocity).max()) <= RESUME_AT_REST_RAD_S
        and float(np.abs(setpoint.acceleration).max()) <= RESUME_AT_REST_RAD_S2)
    if not settled:
        return False
    m.awaiting_rest = False
    target = m.move_target if m.move_status is MoveStatus.WAITING else (
        m.move.target if m.move is not None else None)
    if target is None:
        return True
    try:
        m.move = joint_move(setpoint.position, target, m.planner_limits)
    except (PlanningError, ValueError) as error:
        m.move, m.move_status, m.move_detail = None, MoveStatus.REFUSED, str(error)
        ctx.emit(MotionLine(t=ns_to_ms(ctx.t), request=MotionRequest.MOVE,
                            decision=MotionDecision.REFUSED,
                            move_id=m.move_id, detail=str(error)))
        return True
    m.move_check = None
    if ctx.config.collision is not None and ctx.ask is not None:
        m.move_check = ctx.ask(_clearance_job(m, ctx, m.move, setpoint.position))
        return True
    _play(m, ctx.t, ctx.emit)
    return True


def _play(m: MotionState, t: int, emit: Callable[[Line], None]) -> None:
    if m.move is not None and m.move_status is MoveStatus.WAITING:
        duration = round(m.move.trajectory.duration * 1000.0, 3)
        emit(MotionLine(t=ns_to_ms(t), request=MotionRequest.MOVE,
                        decision=MotionDecision.PLANNED,
                        move_id=m.move_id, duration_ms=duration))
    m.move_status = MoveStatus.PLAYING


MOVE_CHECK_STEP_S = 0.02
"""A planned move is checked at this spacing (and the motion between samples bounded)."""


def _clearance_job(m: MotionState, ctx: MotionContext, move: PlannedMove,
                   start: np.ndarray) -> ClearanceJob:
    duration = move.trajectory.duration
    count = max(1, math.ceil(duration / MOVE_CHECK_STEP_S))
    rows = [move.trajectory.sample(duration * k / count).position for k in range(1, count + 1)]
    collision = ctx.config.collision
    held = collision is not None and collision.holds(m.gripper)
    return ClearanceJob(job_id=0, rows=rows_of(np.array(rows)), start=tuple(start.tolist()),
                        phase=ctx.phase, held=held)


def move_checked(m: MotionState, result: ClearanceResult, t: int,
                 emit: Callable[[Line], None]) -> None:
    """The planned move's clearance: it plays, or it is refused naming the pair."""
    m.move_check = None
    if result.clear:
        _play(m, t, emit)
        return
    detail = collision_detail(result)
    m.move, m.move_status, m.move_detail = None, MoveStatus.REFUSED, detail
    emit(MotionLine(t=ns_to_ms(t), request=MotionRequest.MOVE, decision=MotionDecision.REFUSED,
                    move_id=m.move_id, detail=detail))


def _planner_effect(m: MotionState, q: tuple[float, ...], retreat: bool) -> Motion:
    if retreat:
        return Retreat(q=q, gripper=m.gripper, owner=Owner.PLANNER)
    return Setpoint(q=q, gripper=m.gripper, owner=Owner.PLANNER)


def _contact(m: MotionState, ctx: MotionContext, command: FallbackCommand,
             target: np.ndarray | None, bounded: bool, relax: float | None = None) -> Motion:
    contact = m.contact
    measured = _inside(m, ctx.measured)  # a measured overshoot is never a target
    if command is FallbackCommand.RETREAT:
        retreat(m, ctx, measured)  # checked first where the cell has geometry
    elif relax is not None:
        contact.relax(measured, relax)
    elif contact.state is ContactState.IDLE:
        contact.hold_at(measured)
    offer = np.asarray(target)[ctx.arm] if bounded and target is not None else None
    period_s = ctx.config.control_period_ns * 1e-9
    law = contact.step(ctx.t, period_s, m.force, offer)
    # The law's targets go out as they are: a straight line in task space is a curve in joint
    # space, and an interpolator following it would cut the corner by a millimetre, more than
    # a hole's clearance. They are compliance targets, and continuous: the law starts (and a
    # force-aware retreat starts) where the arm is measured, which is where it already is.
    # Continuous is not slow enough by itself: no target moves faster than the joints' velocity
    # limits (a trial's speed_scale lowers them below what the law's 3 cm/s asks of a wrist).
    reach = ctx.config.limits.velocity[ctx.arm] * period_s
    last = _commanded_array(m)
    _restart(m, last + np.clip(law.q - last, -reach, reach))  # and clipped into the limits
    q = tuple(_commanded_array(m).tolist())
    compliant = ctx.config.motion.impedance
    stiffness = tuple(law.stiffness.tolist()) if compliant else ()
    damping = tuple(law.damping.tolist()) if compliant else ()
    if command is FallbackCommand.RETREAT:
        return Retreat(q=q, gripper=m.gripper, owner=Owner.CONTACT, stiffness=stiffness,
                       damping=damping)
    return Setpoint(q=q, gripper=m.gripper, owner=Owner.CONTACT, stiffness=stiffness,
                    damping=damping)


# -- helpers -----------------------------------------------------------------------------------


def _gripper_of(m: MotionState, ctx: MotionContext, target: np.ndarray | None) -> float | None:
    """A robot whose actions carry the gripper takes it from the action in force."""
    grip = ctx.config.limits.gripper_index
    if grip is None or target is None:
        return m.gripper
    return float(target[grip])


def _interpolator(m: MotionState) -> SetpointInterpolator:
    if m.interpolator is None:  # unreachable: every tick starts the motion layer first
        raise RuntimeError("the motion layer was used before its first tick")
    return m.interpolator


def _commanded_array(m: MotionState) -> np.ndarray:
    return _interpolator(m).setpoint.position if m.commanded is None else m.commanded


def _commanded(m: MotionState, q: np.ndarray) -> tuple[float, ...]:
    m.commanded = np.array(q, dtype=float)
    return tuple(m.commanded.tolist())


def _restart(m: MotionState, q: np.ndarray) -> None:
    _interpolator(m).reset(_inside(m, q))
    m.commanded = _interpolator(m).setpoint.position.copy()


def _inside(m: MotionState, q: np.ndarray) -> np.ndarray:
    """A measured position may sit a hair past a limit (tracking overshoot, a human push) or,
    from a faulty device, not be a number: restart inside the limits, keeping the last
    commanded value for any joint that is not finite."""
    limits = m.interpolator_limits
    position = np.array(q, dtype=float)
    invalid = ~np.isfinite(position)
    if invalid.any():
        fallback = m.commanded if m.commanded is not None else (limits.lower + limits.upper) / 2
        position[invalid] = fallback[invalid]
    return np.clip(position, limits.lower, limits.upper)
