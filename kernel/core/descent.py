"""The contact owner's descent, checked before it starts.

An ``insert`` asks the contact owner (:mod:`skills.contact`) for a guarded descent. Where the
cell has geometry, the descent's path (the law's own IK solutions every few millimetres down to
its end) is checked like a planned move: a clearance job at the phase's clearance, the contact
owner holding compliantly where the arm was until the answer comes; a descent that would break
a pair's clearance does not start, and its ``motion`` line names the pair.

Pure: time is the core's; the job runs where the shell runs jobs.
"""

from __future__ import annotations

from collections.abc import Callable

from assurance.clock import ns_to_ms
from kernel.core.jobs import ClearanceJob, ClearanceResult, rows_of
from kernel.core.lines import Line, MotionDecision, MotionLine, MotionRequest
from kernel.core.motion_state import MotionContext, MotionState, collision_detail
from skills.contact import Descent, DescentStatus, NoKinematics

DESCENT_CHECK_STEP_M = 0.005
"""The contact owner's descent is checked every this much of the tool's height (and the
motion between the samples bounded, as a chunk's)."""


def request_descent(m: MotionState, ctx: MotionContext, descent: Descent) -> bool:
    """An ``insert``: with the cell's geometry, the descent's path is checked before it starts
    (the contact owner holds where the arm was meanwhile) and False is returned; without it,
    the descent starts now and True is returned. An insert whose check is still pending is
    superseded: its ``motion`` line says so.

    Raises:
        NoKinematics: there is no kinematic model to descend with.
        ValueError: the descent's pose is not one the kinematics can solve for, or the descent
            is longer than an insertion can be (:data:`skills.contact.MAX_DESCENT_M`).
    """
    collision = ctx.config.collision
    if m.descent_check is not None:
        _decided(m, ctx.t, ctx.emit, "superseded by a later insert")
    if collision is None or ctx.ask is None:
        m.contact.start(descent)
        m.descent_status = DescentStatus.STARTED
        return True
    path = m.contact.descent_path(descent, DESCENT_CHECK_STEP_M)
    m.contact.hold_at(descent.q)
    m.descent, m.descent_asked = descent, (m.contact.generation, ctx.phase)
    m.descent_status = DescentStatus.CHECKING
    m.descent_check = ctx.ask(ClearanceJob(
        job_id=0, rows=rows_of(path), start=tuple(descent.q.tolist()), phase=ctx.phase,
        held=collision.holds(m.gripper)))
    return False


def descent_checked(m: MotionState, result: ClearanceResult, t: int,
                    emit: Callable[[Line], None], phase: str, in_control: bool) -> None:
    """The descent's clearance: it starts if the contact owner still holds where the insert
    found the arm, in the same phase, with the policy's phases running (``in_control``: not a
    fallback that took the arm meanwhile); otherwise it is refused, naming the pair or what
    moved on."""
    descent = m.descent
    detail = None
    if not result.clear:
        detail = collision_detail(result)
    elif descent is None or m.descent_asked != (m.contact.generation, phase) or not in_control:
        detail = (f"superseded: the contact owner is {m.contact.state} in {phase} now"
                  + ("" if in_control else ", not in control"))
    else:
        try:
            m.contact.start(descent)
        except (NoKinematics, ValueError) as error:  # checked once already: not expected
            detail = str(error)
    _decided(m, t, emit, detail)


def drop_descent(m: MotionState, t: int, emit: Callable[[Line], None], why: str) -> None:
    """The task entered or left a contact phase: a descent still being checked is refused
    (``why``), and the new phase starts with no descent asked for."""
    if m.descent_check is not None:
        _decided(m, t, emit, why)
    m.descent_status = DescentStatus.NONE


def _decided(m: MotionState, t: int, emit: Callable[[Line], None], refused: str | None) -> None:
    """The pending descent is decided: the line, and the status the task reads."""
    m.descent_check, m.descent = None, None
    m.descent_status = DescentStatus.REFUSED if refused else DescentStatus.STARTED
    emit(MotionLine(t=ns_to_ms(t), request=MotionRequest.INSERT,
                    decision=MotionDecision.REFUSED if refused else MotionDecision.STARTED,
                    detail=refused))
