"""The contact owner: a force-guarded compliant insertion and a force-aware retreat.

From contact onset this law owns motion. It lowers the tool along a vertical axis at a fixed
speed in joint impedance mode, re-solving IK for the descent's tool orientation each tick, and
stops when the target depth is reached or the measured force says the part has landed. A target
offered by an admitted chunk is only ever a bounded correction of its own nominal target: it
is clipped to ``max_target_offset`` and never replaces the law. The retreat lifts along the
same axis, compliantly, until the tool is back at the start height. A relaxed hold stops
pressing where the tool is, at a fraction of the stiffness (the phase card's choice when the
policy link is lost, ``link_loss = "hold"``).

Without a kinematic model the law can only hold compliantly where contact began: a descent is
refused (:class:`NoKinematics`) and a retreat holds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from assurance.kinematics import ArmKinematics, Pose


class ContactState(StrEnum):
    IDLE = "idle"
    HOLDING = "holding"
    DESCENDING = "descending"
    DWELLING = "dwelling"
    DONE = "done"
    RETREATING = "retreating"
    RETREATED = "retreated"
    RELAXED = "relaxed"
    """Stopped pressing: a soft compliant hold where the tool was (the policy link is lost)."""


_STIFFNESS = (1500.0, 1500.0, 1000.0, 200.0, 200.0, 200.0)
"""N·m/rad per joint of a 6-joint arm: stiff shoulder and elbow, soft wrist."""
_INERTIA = (2.0, 2.0, 0.6, 0.15, 0.15, 0.12)
"""kg·m², about what each joint of a UR5e-class arm carries: damping is critical for it."""


class DescentStatus(StrEnum):
    """What became of the last descent an ``insert`` asked for (the task reads it)."""

    NONE = "none"
    CHECKING = "checking"
    """Its path's clearance is being checked; the contact owner holds meanwhile."""
    STARTED = "started"
    REFUSED = "refused"


MAX_DESCENT_M = 0.5
"""The longest descent a path check looks at: an insertion is centimetres; further is a
mistake, refused before any work."""


RETREAT_LIFT_M = 0.02
"""How far a retreat lifts the tool when no descent ran (from a hold)."""


@dataclass(frozen=True, slots=True, eq=False)
class RetreatPlan:
    """A force-aware retreat, planned: the tool from ``q``'s pose (height ``z``) straight up to
    ``z_start``, along the vertical through ``xy``, held at ``rotation``."""

    q: np.ndarray
    z: float
    z_start: float
    xy: np.ndarray
    rotation: np.ndarray


class NoKinematics(ValueError):
    """A Cartesian descent was asked of a contact owner that has no kinematic model."""


@dataclass(frozen=True, slots=True, eq=False)
class ContactConfig:
    speed_m_s: float = 0.03
    retreat_speed_m_s: float = 0.04
    stop_force_n: float = 12.0
    """Force (norm) at which the descent stops: the part has landed."""
    dwell_s: float = 0.25
    max_target_offset: float = 0.002
    """Largest correction (rad per joint) a bounded target may add to the law's own target."""
    stiffness: np.ndarray = field(default_factory=lambda: np.array(_STIFFNESS))
    damping: np.ndarray = field(default_factory=lambda: 2 * np.sqrt(
        np.array(_STIFFNESS) * np.array(_INERTIA)))

    def for_dof(self, dof: int) -> ContactConfig:
        """These gains for an arm of ``dof`` joints (other than six: the mean gain on each)."""
        if self.stiffness.shape == (dof,):
            return self
        stiffness = np.full(dof, float(self.stiffness.mean()))
        damping = np.full(dof, float(self.damping.mean()))
        return ContactConfig(self.speed_m_s, self.retreat_speed_m_s, self.stop_force_n,
                             self.dwell_s, self.max_target_offset, stiffness, damping)


@dataclass(frozen=True, slots=True, eq=False)
class ContactCommand:
    q: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    state: ContactState


@dataclass(frozen=True, slots=True, eq=False)
class Descent:
    """The contact owner's guarded descent an ``insert`` asks for: from ``q`` (where the arm
    was measured) down to ``z_end`` along the vertical through ``xy``, the tool held at
    ``rotation``."""

    q: np.ndarray
    xy: np.ndarray
    z_end: float
    rotation: np.ndarray


class ContactOwner:
    def __init__(self, kinematics: ArmKinematics | None,
                 config: ContactConfig | None = None) -> None:
        self.kin = kinematics
        self.config = config or ContactConfig()
        self.state = ContactState.IDLE
        self._xy = np.zeros(2)
        self._rotation = np.eye(3)
        self._z = self._z_start = self._z_end = 0.0
        self._q = np.zeros(self.config.stiffness.shape[0])
        self._dwell_until = 0
        self._softness = 1.0
        """The fraction of the law's stiffness in force (1 but in a relaxed hold)."""
        self.generation = 0
        """Counts every change of what the law does (a start, a hold, a retreat, a relaxed
        hold, a new cycle): an answer about one of them is stale once it has moved on."""

    def start(self, descent: Descent) -> None:
        """Begin ``descent``: from the tool's height at its ``q`` down to its ``z_end``, along
        the vertical through its ``xy``, holding the tool at its ``rotation``.

        Raises:
            NoKinematics: there is no kinematic model to descend with.
        """
        kin = self._kinematics()
        self._q = np.asarray(descent.q, dtype=float).copy()
        self._xy = np.asarray(descent.xy, float)
        self._rotation = np.asarray(descent.rotation, float)
        self._z = self._z_start = float(kin.forward(self._q).position[2])
        self._z_end = float(descent.z_end)
        self._softness = 1.0
        self.state = ContactState.DESCENDING
        self.generation += 1

    def descent_path(self, descent: Descent, step_m: float) -> np.ndarray:
        """The configurations ``descent`` would pass through, every ``step_m`` of height and
        at its ``z_end``, each solved from the one before as the law solves its targets: what
        a clearance check looks at before the descent may start. A ``z_end`` above the tool is
        reached in one step, as the law reaches it.

        Raises:
            NoKinematics: there is no kinematic model to descend with.
            ValueError: the descent is longer than :data:`MAX_DESCENT_M`.
        """
        kin = self._kinematics()
        current = np.asarray(descent.q, dtype=float).copy()
        z_start = float(kin.forward(current).position[2])
        if not abs(z_start - descent.z_end) <= MAX_DESCENT_M:
            raise ValueError(f"a descent from {z_start:.3f} m to {descent.z_end:.3f} m is longer "
                             f"than {MAX_DESCENT_M} m")
        count = max(1, math.ceil(max(z_start - descent.z_end, 0.0) / step_m))
        heights = [z_start + (descent.z_end - z_start) * (k + 1) / count for k in range(count)]
        return _solve_along(kin, current, descent.xy, descent.rotation, heights)

    def reset(self) -> None:
        """A new cycle: nothing to descend, hold or retreat from."""
        self._softness = 1.0
        self.state = ContactState.IDLE
        self.generation += 1

    def relax(self, q: np.ndarray, factor: float) -> None:
        """Stop pressing: hold ``q`` (where the tool is) compliantly, the stiffness scaled by
        ``factor`` in (0, 1] and the damping by its square root (still critically damped).
        The pose is taken once: a relaxed hold stays where it began."""
        if self.state is ContactState.RELAXED:
            return
        self._q = np.asarray(q, dtype=float).copy()
        self._softness = float(factor)
        self.state = ContactState.RELAXED
        self.generation += 1

    def hold_at(self, q: np.ndarray) -> None:
        """Compliantly hold ``q`` (contact owned without a descent to run)."""
        self._q = np.asarray(q, dtype=float).copy()
        self.state = ContactState.HOLDING
        self.generation += 1

    def begin_retreat(self, q: np.ndarray) -> None:
        """Force-aware retreat from wherever the tool is now back up to the start height (2 cm
        up, if no descent ran); without a kinematic model, a compliant hold where it is."""
        if self.state in (ContactState.RETREATING, ContactState.RETREATED):
            return
        self.start_retreat(self.plan_retreat(q), q)

    def plan_retreat(self, q: np.ndarray) -> RetreatPlan | None:
        """The retreat :meth:`begin_retreat` would run from ``q`` now, without starting it (None
        without a kinematic model): after a descent, back up its axis to the height it began
        at; otherwise 2 cm straight up."""
        if self.kin is None:
            return None
        start = np.asarray(q, dtype=float).copy()
        pose = self.kin.forward(start)
        z = float(pose.position[2])
        if self.state in (ContactState.IDLE, ContactState.HOLDING, ContactState.RELAXED):
            return RetreatPlan(start, z, z + RETREAT_LIFT_M, pose.position[:2].copy(),
                               pose.rotation.copy())
        return RetreatPlan(start, z, self._z_start, self._xy.copy(), self._rotation.copy())

    def start_retreat(self, plan: RetreatPlan | None, q: np.ndarray) -> None:
        """Run ``plan`` (None: hold compliantly at ``q``, there being no model to lift with)."""
        self._softness = 1.0
        self._q = np.asarray(q if plan is None else plan.q, dtype=float).copy()
        self.generation += 1
        if plan is None:
            self.state = ContactState.RETREATED
            return
        self._z, self._z_start = plan.z, plan.z_start
        self._xy, self._rotation = plan.xy, plan.rotation
        self.state = ContactState.RETREATING

    def retreat_path(self, plan: RetreatPlan, step_m: float) -> np.ndarray:
        """The configurations ``plan`` passes through, every ``step_m`` of height and at its
        end, each solved from the one before as the law solves them (what a clearance check
        looks at before the retreat may start); one row, where it is, when it has nowhere to
        go."""
        rise = max(plan.z_start - plan.z, 0.0)
        count = max(1, math.ceil(rise / step_m - 1e-9))  # 2 cm in 5 mm steps: 4, not 5
        heights = [plan.z + rise * (k + 1) / count for k in range(count)]
        return _solve_along(self._kinematics(), plan.q, plan.xy, plan.rotation, heights)

    def step(self, now_ns: int, dt_s: float, force_norm: float,
             bounded_target: np.ndarray | None = None) -> ContactCommand:
        cfg = self.config
        if self.state is ContactState.DESCENDING:
            self._descend(now_ns, dt_s, force_norm)
        elif self.state is ContactState.DWELLING and now_ns >= self._dwell_until:
            self.state = ContactState.DONE
        elif self.state is ContactState.RETREATING:
            self._z = min(self._z + cfg.retreat_speed_m_s * dt_s, self._z_start)
            if self._z >= self._z_start:
                self.state = ContactState.RETREATED
        if self.state in (ContactState.DESCENDING, ContactState.RETREATING):
            self._q = self._solve(self._z)
        target = self._q
        if bounded_target is not None:
            offset = np.clip(np.asarray(bounded_target) - self._q, -cfg.max_target_offset,
                             cfg.max_target_offset)
            target = self._q + offset
        if self._softness == 1.0:
            return ContactCommand(target, cfg.stiffness, cfg.damping, self.state)
        return ContactCommand(target, cfg.stiffness * self._softness,
                              cfg.damping * np.sqrt(self._softness), self.state)

    def _descend(self, now_ns: int, dt_s: float, force_norm: float) -> None:
        landed = force_norm >= self.config.stop_force_n
        self._z = max(self._z - self.config.speed_m_s * dt_s, self._z_end)
        if landed or self._z <= self._z_end:
            self.state = ContactState.DWELLING
            self._dwell_until = now_ns + int(self.config.dwell_s * 1e9)

    def _solve(self, z: float) -> np.ndarray:
        target = Pose(np.array([self._xy[0], self._xy[1], z]), self._rotation)
        return self._kinematics().solve(target, self._q).q

    def _kinematics(self) -> ArmKinematics:
        if self.kin is None:
            raise NoKinematics("no kinematic model: the contact owner can only hold")
        return self.kin


def _solve_along(kin: ArmKinematics, q: np.ndarray, xy: np.ndarray, rotation: np.ndarray,
                 heights: list[float]) -> np.ndarray:
    """The configurations at each of ``heights`` on the vertical through ``xy``, the tool at
    ``rotation``, each solved from the one before (from ``q`` first), as the law solves its
    targets: the paths a descent's and a retreat's checks look at."""
    current = np.asarray(q, dtype=float).copy()
    rows = np.empty((len(heights), current.shape[0]))
    for k, z in enumerate(heights):
        target = Pose(np.array([xy[0], xy[1], z]), rotation)
        current = rows[k] = kin.solve(target, current).q
    return rows
