"""The clearance check of a chunk's rows (:mod:`assurance.collision`), as admission asks for it.

The rows are the ones the merge would queue (after trim, replace and blend, projected), from the
setpoint they follow; the part counts as held when the commanded gripper (or any row's gripper
column) is closed on it. The check itself runs in a job (:mod:`kernel.core.jobs`): even its
shortcut (:meth:`~assurance.collision.CellCollision.clear_by_travel`, one distance query for the
whole motion) costs a few hundred microseconds, a fifth of a control period, and most chunks of
the cell's learned approach come near the fixture, where the shortcut cannot decide.
"""

from __future__ import annotations

from assurance.merge import MergePlan
from kernel.core.jobs import ClearanceJob, ClearanceResult, rows_of
from kernel.core.lines import CollisionLine
from kernel.core.state import CoreState

_CLEARANCE_DIGITS = 6


def clearance_job(state: CoreState, plan: MergePlan) -> ClearanceJob:
    """The clearance check of the rows the plan would queue, from the setpoint they follow."""
    arm = state.config.limits.arm_mask
    actions = plan.projection.actions
    collision = state.config.collision
    grip = state.config.limits.gripper_index
    held = collision is not None and (collision.holds(state.motion.gripper) or (
        grip is not None and any(collision.holds(g) for g in actions[:, grip].tolist())))
    return ClearanceJob(job_id=0, rows=rows_of(actions[:, arm]),
                        start=tuple(plan.segment.ref_q[arm].tolist()),
                        phase=str(state.task.phase), held=held)


def collision_line(result: ClearanceResult) -> CollisionLine:
    return CollisionLine(pair=result.pair, action=result.action,
                         distance=round(result.distance, _CLEARANCE_DIGITS),
                         bound=round(result.bound, _CLEARANCE_DIGITS),
                         needed=round(result.needed, _CLEARANCE_DIGITS))
