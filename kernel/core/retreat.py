"""The contact owner's force-aware retreat, checked before it starts.

A contact fallback (``CONTACT_FALLBACK``, or a lost link whose phase card says ``retract``)
has the contact owner lift the tool straight up, back to the height its descent began at (2 cm
without one). Where the cell has geometry, that path (the law's own IK solutions every few
millimetres) is checked like a descent: a clearance job at the phase's clearance, the contact
owner holding compliantly where the arm was until the answer comes. A retreat that would break
a pair's clearance (an overhang above the fixture, a keep-out zone over the cell) does not
start: the contact owner keeps holding, the ``motion`` line (``retreat``) names the pair, and
it is not asked again until the fallback ends (a check that could not run, the job worker busy
or restarting, is asked again 100 ms later). Holding where contact ended is the safe answer
the contact owner already gives when it has no model to lift with.

Pure: time is the core's; the job runs where the shell runs jobs.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from assurance.clock import ns_to_ms
from kernel.core.jobs import ClearanceJob, ClearanceResult, rows_of
from kernel.core.lines import Line, MotionDecision, MotionLine, MotionRequest
from kernel.core.motion_state import NOT_CHECKED, MotionContext, MotionState, collision_detail
from skills.contact import ContactState

RETREAT_CHECK_STEP_M = 0.005
"""The retreat is checked every this much of the tool's height (the motion between the samples
bounded, as a chunk's)."""
RETRY_AFTER_NS = 100_000_000
"""A check that could not run (the worker busy or restarting) is asked again this much later,
for the same retreat; a COLLISION answer is final until the fallback ends."""


def retreat(m: MotionState, ctx: MotionContext, measured: np.ndarray) -> None:
    """One tick of a contact retreat: start it, ask for its check, or keep waiting (or
    holding, once refused)."""
    contact = m.contact
    if (contact.state in (ContactState.RETREATING, ContactState.RETREATED)
            or m.retreat_check is not None or m.retreat_refused or ctx.t < m.retreat_retry_at):
        return
    retrying = m.retreat_plan is not None and m.retreat_asked == contact.generation
    plan = m.retreat_plan if retrying else contact.plan_retreat(measured)
    collision = ctx.config.collision
    if collision is None or ctx.ask is None or plan is None:
        contact.start_retreat(plan, measured)
        return
    path = contact.retreat_path(plan, RETREAT_CHECK_STEP_M)
    if not retrying:  # a retry holds where the first ask did, for the retreat it planned
        contact.hold_at(measured)
    m.retreat_plan, m.retreat_asked = plan, contact.generation
    m.retreat_check = ctx.ask(ClearanceJob(
        job_id=0, rows=rows_of(path), start=tuple(plan.q.tolist()), phase=ctx.phase,
        held=collision.holds(m.gripper)))


def retreat_checked(m: MotionState, result: ClearanceResult, t: int,
                    emit: Callable[[Line], None]) -> None:
    """The retreat's clearance: it starts if the contact owner still holds where it was asked
    from; otherwise it is refused, naming the pair or what moved on."""
    plan = m.retreat_plan
    m.retreat_check = None
    detail = None
    if result.pair == NOT_CHECKED:  # transient: the same retreat is asked again, later
        detail = collision_detail(result) + f"; asked again in {RETRY_AFTER_NS // 1_000_000} ms"
        m.retreat_retry_at = t + RETRY_AFTER_NS
        _line(t, emit, detail)
        return
    m.retreat_plan = None
    if not result.clear:
        detail = collision_detail(result)
        m.retreat_refused = True
    elif plan is None or m.retreat_asked != m.contact.generation:
        detail = f"superseded: the contact owner is {m.contact.state} now"
    else:
        m.contact.start_retreat(plan, plan.q)
    _line(t, emit, detail)


def drop_retreat(m: MotionState, t: int, emit: Callable[[Line], None]) -> None:
    """The contact owner is no longer asked to retreat: a check still pending is refused, and
    a refusal is forgotten (the next contact fallback asks again). Called on every tick that
    is not a contact retreat: nothing to forget is the common case, and costs one test."""
    if m.retreat_plan is None and not (m.retreat_refused or m.retreat_retry_at):
        return  # a pending check always has its plan
    if m.retreat_check is not None:
        _line(t, emit, "superseded: the retreat is no longer commanded")
    m.retreat_check, m.retreat_plan, m.retreat_refused = None, None, False
    m.retreat_retry_at = 0


def _line(t: int, emit: Callable[[Line], None], refused: str | None) -> None:
    emit(MotionLine(t=ns_to_ms(t), request=MotionRequest.RETREAT,
                    decision=MotionDecision.REFUSED if refused else MotionDecision.STARTED,
                    detail=refused))
