"""The motion layer's state, and what it reads from the rest of the core for one tick
(:mod:`kernel.core.motion` turns both into the command that reaches the arm; the planner's
move, the contact owner's descent and its retreat are checked through it).

Pure: time is the core's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from kernel.core.config import CoreConfig
from kernel.core.jobs import ClearanceJob, ClearanceResult
from kernel.core.lines import Line
from skills.contact import ContactOwner, Descent, DescentStatus, RetreatPlan
from skills.interpolator import SetpointInterpolator
from skills.planner import MoveStatus, PlannedMove
from skills.trajectory import MotionLimits


@dataclass(slots=True, eq=False)
class MotionState:
    """The motion layer's state inside :class:`~kernel.core.state.CoreState`."""

    interpolator_limits: MotionLimits
    planner_limits: MotionLimits
    contact: ContactOwner
    interpolator: SetpointInterpolator | None = None
    commanded: np.ndarray | None = None
    gripper: float | None = None
    force: float = 0.0
    move: PlannedMove | None = None
    move_id: int = 0
    move_target: np.ndarray | None = None
    move_status: MoveStatus = MoveStatus.NONE
    move_detail: str = ""
    planner_had_tick: bool = False
    awaiting_rest: bool = False
    rest_target: np.ndarray = field(default_factory=lambda: np.zeros(0))
    move_check: int | None = None
    """The clearance job of the planned move, while its answer is awaited (the arm stays at
    rest until the move is cleared)."""
    descent_check: int | None = None
    """The clearance job of the contact owner's descent, while its answer is awaited (the
    contact owner holds where the arm was until the descent is cleared)."""
    descent: Descent | None = None
    """The descent that job is for."""
    descent_asked: tuple[int, str] = (0, "")
    """The contact owner's generation and the task phase when that job was asked for: an
    answer after either changed is about a descent nobody holds for any more."""
    descent_status: DescentStatus = DescentStatus.NONE
    retreat_check: int | None = None
    """The clearance job of the contact owner's retreat, while its answer is awaited (the
    contact owner holds where the arm was until the retreat is cleared)."""
    retreat_plan: RetreatPlan | None = None
    retreat_asked: int = 0
    """The contact owner's generation when that job was asked for."""
    retreat_refused: bool = False
    """The retreat's path breaks a clearance: the contact owner holds until the fallback ends."""
    retreat_retry_at: int = 0
    """Its check could not run: not asked again before this time (ns)."""


def initial_motion(config: CoreConfig) -> MotionState:
    limits, motion = config.limits, config.motion
    arm = MotionLimits.from_joint_limits(limits, motion.interpolator_jerk)
    velocity = np.minimum(arm.velocity, motion.planner_velocity)
    planner = MotionLimits(arm.lower, arm.upper, velocity,
                           np.minimum(arm.acceleration, motion.planner_acceleration),
                           np.full(arm.dof, motion.planner_jerk))
    contact = ContactOwner(config.kinematics, motion.contact.for_dof(arm.dof))
    return MotionState(arm, planner, contact)


class MotionContext:
    """What the motion layer reads from the rest of the core for one tick, and where it logs.
    ``ask``: asks for a job and returns its id (a planned move's clearance check)."""

    __slots__ = ("arm", "ask", "config", "emit", "measured", "phase", "t")

    def __init__(self, config: CoreConfig, t: int, measured_q: np.ndarray,
                 emit: Callable[[Line], None], phase: str = "",
                 ask: Callable[[ClearanceJob], int] | None = None) -> None:
        self.config = config
        self.t = t
        self.arm = config.limits.arm_mask
        self.measured = measured_q[self.arm]
        self.emit = emit
        self.phase = phase
        self.ask = ask


NOT_CHECKED = ("not", "checked")
"""The pair of a clearance result that stands for a check that could not run."""


def collision_detail(result: ClearanceResult) -> str:
    """What a refused motion's line says: the pair, its distance and the clearance."""
    if result.pair == NOT_CHECKED:
        return "not checked: its clearance job could not run, and nothing moves unchecked"
    return (f"COLLISION: {result.pair[0]} and {result.pair[1]} at {result.distance:.4f} m "
            f"(at least {result.bound:.4f} m on the way) need {result.needed:.4f} m")
