"""Joint-space feasibility projection (seed §2): ``a_sent = Π_C(s)(a_proposed)``.

A chunk is a sequence of joint setpoints on its own action grid (spacing ``dt``). The admissible
set keeps every setpoint inside the position limits, every step inside the velocity limit, every
change of step inside the acceleration limit, and every state *brakeable*: from each setpoint the
joint can still stop inside its position limits without exceeding the acceleration limit. That
last condition is what makes the projection recursively feasible: a projected sequence can
always be continued (by decelerating), so a later chunk or a hold never inherits an impossible
state.

Step units: ``V = v_max·dt`` and ``A = a_max·dt²`` so that velocity and acceleration bounds are
bounds on a step and on a change of step. With a step ``s > 0`` and ``m = floor(s/A)``, the
distance still travelled while braking at the limit is ``B(s) = m·s − A·m(m+1)/2``, and
``g(s) = s + B(s)`` is piecewise linear and increasing, so its inverse has a closed form.

The common case (a feasible proposal) is checked in one vectorized pass; only joints that
violate a bound fall back to the exact sequential projection, from their first violation on.
The gripper dimension is only clipped to its position limits: a gripper event is a step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from assurance.limits import JointLimits

_EPS = 1e-9


@dataclass(frozen=True, slots=True, eq=False)
class Projection:
    """The projected actions and how far each one moved (max-abs over dimensions)."""

    actions: np.ndarray
    distances: np.ndarray
    recoverable: bool
    """False when the reference itself could not be continued inside the limits."""

    @property
    def max_distance(self) -> float:
        return float(self.distances.max()) if self.distances.size else 0.0


@dataclass(frozen=True, slots=True, eq=False)
class Reference:
    """The last commanded setpoint before the chunk and its step on the same grid."""

    q: np.ndarray
    step: np.ndarray


def braking_distance(step: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """Extra distance travelled in the direction of ``step`` while braking at ``acc`` per step²."""
    s = np.abs(step)
    bounded = np.isfinite(acc)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        m = np.floor(s / acc)
        reach = m * s - acc * m * (m + 1.0) / 2.0
    return np.where(bounded & np.isfinite(reach), reach, 0.0)


def max_step_toward(room: float, acc: float) -> float:
    """The largest step ``s`` with ``g(s) <= room`` (inverse of the braking reach)."""
    if room <= 0.0 or math.isinf(room) or math.isinf(acc):
        return room
    m = math.floor((-1.0 + math.sqrt(1.0 + 8.0 * room / acc)) / 2.0)
    return (room + acc * m * (m + 1) / 2.0) / (m + 1)


def project(
    actions: np.ndarray, reference: Reference, dt_s: float, limits: JointLimits
) -> Projection:
    """Project ``actions`` (H×D) into the limits, starting from ``reference``."""
    v_step = limits.velocity * dt_s
    a_step = limits.acceleration * dt_s * dt_s
    violating = _violations(actions, reference, v_step, a_step, limits)
    projected = actions.copy()
    recoverable = True
    for joint in np.flatnonzero(violating.any(axis=0)):
        if limits.gripper_index == joint:
            np.clip(projected[:, joint], limits.lower[joint], limits.upper[joint],
                    out=projected[:, joint])
            continue
        first = int(np.argmax(violating[:, joint]))
        recoverable &= _project_joint(projected, joint, first, reference, v_step, a_step, limits)
    distances = np.abs(projected - actions).max(axis=1) if actions.size else np.zeros(0)
    projected.setflags(write=False)
    return Projection(projected, distances, recoverable)


def _violations(
    actions: np.ndarray, ref: Reference, v_step: np.ndarray, a_step: np.ndarray,
    limits: JointLimits,
) -> np.ndarray:
    """Boolean H×D: which entries break a bound, checked on the proposal as it stands."""
    lower, upper = limits.lower - _EPS, limits.upper + _EPS
    out = (actions < lower) | (actions > upper)
    arm = limits.arm_mask
    steps = np.diff(actions, axis=0, prepend=ref.q[np.newaxis, :])
    changes = np.diff(steps, axis=0, prepend=ref.step[np.newaxis, :])
    reach = braking_distance(steps, a_step)
    ahead = actions + np.where(steps > 0, reach, -reach)
    rate = (np.abs(steps) > v_step + _EPS) | (np.abs(changes) > a_step + _EPS)
    rate |= (ahead > upper) | (ahead < lower)
    out[:, arm] |= rate[:, arm]
    return out


def _project_joint(
    projected: np.ndarray, joint: int, first: int, ref: Reference,
    v_step: np.ndarray, a_step: np.ndarray, limits: JointLimits,
) -> bool:
    """Exact sequential projection of one joint from row ``first`` on; False if unrecoverable."""
    lo, hi = float(limits.lower[joint]), float(limits.upper[joint])
    vmax, acc = float(v_step[joint]), float(a_step[joint])
    column = projected[:, joint]
    if first == 0:
        p, s = float(ref.q[joint]), float(ref.step[joint])
    else:
        p = float(column[first - 1])
        s = p - (float(column[first - 2]) if first >= 2 else float(ref.q[joint]))
    recoverable = True
    for row in range(first, column.shape[0]):
        low = max(-vmax, s - acc, -max_step_toward(p - lo, acc))
        high = min(vmax, s + acc, max_step_toward(hi - p, acc))
        if low > high + _EPS:
            # The reference itself cannot be continued inside the limits: brake as hard as
            # allowed and let the caller refuse the chunk.
            recoverable = False
            low = high = max(s - acc, min(s + acc, 0.0))
        s = min(max(float(column[row]) - p, low), high)
        p = min(max(p + s, lo), hi)
        column[row] = p
    return recoverable


def check_sequence(
    actions: np.ndarray, reference: Reference, dt_s: float, limits: JointLimits
) -> bool:
    """True when ``actions`` already satisfy every bound (the test oracle for projection)."""
    v_step = limits.velocity * dt_s
    a_step = limits.acceleration * dt_s * dt_s
    return not _violations(actions, reference, v_step, a_step, limits).any()
