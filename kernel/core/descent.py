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
from kernel.core.motion import MotionContext, MotionState, collision_detail
from skills.contact import ContactState, Descent, NoKinematics

DESCENT_CHECK_STEP_M = 0.005
"""The contact owner's descent is checked every this much of the tool's height (and the
motion between the samples bounded, as a chunk's)."""


def request_descent(m: MotionState, ctx: MotionContext, descent: Descent) -> bool:
    """An ``insert``: with the cell's geometry, the descent's path is checked before it starts
    (the contact owner holds where the arm was meanwhile) and False is returned; without it,
    the descent starts now and True is returned.

    Raises:
        NoKinematics: there is no kinematic model to descend with.
        ValueError: the descent's pose is not one the kinematics can solve for.
    """
    collision = ctx.config.collision
    m.descent_check, m.descent = None, None  # an earlier insert's check answers for it alone
    if collision is None or ctx.ask is None:
        m.contact.begin(descent)
        return True
    path = m.contact.descent_path(descent, DESCENT_CHECK_STEP_M)
    m.contact.hold_at(descent.q)
    m.descent = descent
    m.descent_check = ctx.ask(ClearanceJob(
        job_id=0, rows=rows_of(path), start=tuple(descent.q.tolist()), phase=ctx.phase,
        held=collision.holds(m.gripper)))
    return False


def descent_checked(m: MotionState, result: ClearanceResult, t: int,
                    emit: Callable[[Line], None]) -> None:
    """The descent's clearance: it starts (if the contact owner still holds where the insert
    found the arm), or it is refused naming the pair."""
    descent, m.descent, m.descent_check = m.descent, None, None
    detail = None
    if not result.clear:
        detail = collision_detail(result)
    elif descent is None or m.contact.state is not ContactState.HOLDING:
        detail = f"superseded: the contact owner is {m.contact.state} now"
    else:
        try:
            m.contact.begin(descent)
        except (NoKinematics, ValueError) as error:  # checked once already: not expected
            detail = str(error)
    decision = MotionDecision.REFUSED if detail else MotionDecision.STARTED
    emit(MotionLine(t=ns_to_ms(t), request=MotionRequest.INSERT, decision=decision,
                    detail=detail))
