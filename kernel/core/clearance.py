"""The clearance check of a chunk's rows (:mod:`assurance.collision`), as admission asks for it.

The rows are the ones the merge would queue (after trim, replace and blend, projected), from the
setpoint they follow; the part counts as held when the commanded gripper (or any row's gripper
column) is closed on it. Away from every solid one distance query proves the rows clear, on the
step that admits them (:meth:`~assurance.collision.CellCollision.clear_by_travel`); otherwise
the exact check runs in a job (:mod:`kernel.core.jobs`).
"""

from __future__ import annotations

import numpy as np

from assurance.merge import MergePlan
from kernel.core.jobs import ClearanceJob, ClearanceResult, array_of, rows_of
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


def clear_at_a_glance(state: CoreState, job: ClearanceJob) -> bool:
    """Whether one distance query at the job's start proves every row clear (pure: the same on
    replay)."""
    collision = state.config.collision
    return collision is not None and collision.clear_by_travel(
        np.array(job.start), array_of(job.rows, collision.dof), job.phase, job.held)


def collision_line(result: ClearanceResult) -> CollisionLine:
    return CollisionLine(pair=result.pair, action=result.action,
                         distance=round(result.distance, _CLEARANCE_DIGITS),
                         bound=round(result.bound, _CLEARANCE_DIGITS),
                         needed=round(result.needed, _CLEARANCE_DIGITS))
