"""Joint-space feasibility projection: ``a_sent = Π_C(s)(a_proposed)``.

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
from dataclasses import dataclass, field

import msgspec
import numpy as np

from assurance.limits import JointLimits

_EPS = 1e-9
_ROUNDING_ULPS = 8
"""Rounding of the band's bounds, centre, half-width and of ``x − mid``: under 4 ulps in all."""
_ULP = float(np.finfo(float).eps)


class Projection(msgspec.Struct, frozen=True, eq=False):
    """The projected actions and how far each one moved (max-abs over dimensions)."""

    actions: np.ndarray
    distances: np.ndarray
    recoverable: bool
    """False when the reference itself could not be continued inside the limits."""
    max_distance: float = 0.0


class Reference(msgspec.Struct, frozen=True, eq=False):
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
    ratio = 8.0 * room / acc
    if math.isinf(ratio):  # an astronomical room: the continuous inverse, a lower bound
        return max(0.0, math.sqrt(2.0 * acc) * math.sqrt(room) - acc)
    m = math.floor((-1.0 + math.sqrt(1.0 + ratio)) / 2.0)
    return (room + acc * m * (m + 1) / 2.0) / (m + 1)


@dataclass(frozen=True, slots=True, eq=False)
class _Bounds:
    """The limits on one action grid, in step units, computed once per (limits, dt)."""

    lower: np.ndarray
    upper: np.ndarray
    v_step: np.ndarray
    a_step: np.ndarray
    a_finite: np.ndarray
    """``a_step`` with 0 where unbounded: the braking reach of such a joint is 0."""
    inv_a: np.ndarray
    """1/``a_step``, 0 where unbounded."""
    arm: np.ndarray
    margin: np.ndarray
    """The furthest any step the rate check lets through can carry a joint, braking included:
    further than this from a limit, braking toward it never binds."""
    mid: np.ndarray
    """Centre of the band in which no admissible step can reach a position limit, braking
    included (the usual case, far from the joint limits); the gripper's band is its limits."""
    kind_bounds: np.ndarray
    """Per row kind (step, change of step, distance from ``mid``), the largest admissible
    magnitude: 3×D, infinite where unbounded, −∞ where no band exists (never admitted)."""
    band_cache: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False)

    def band(self, horizon: int) -> tuple[np.ndarray, np.ndarray]:
        """The 3H×D magnitude bounds of a horizon-``horizon`` chunk, and H zeros (read-only)."""
        cached = self.band_cache.get(horizon)
        if cached is None:
            if len(self.band_cache) >= 8:  # a policy sends one or two horizons; bound the rest
                self.band_cache.clear()
            rows = np.repeat(self.kind_bounds, horizon, axis=0)
            zeros = np.zeros(horizon)
            rows.setflags(write=False)
            zeros.setflags(write=False)
            cached = self.band_cache[horizon] = (rows, zeros)
        return cached


_bounds_cache: dict[tuple[int, float], tuple[JointLimits, _Bounds]] = {}


def _bounds(limits: JointLimits, dt_s: float) -> _Bounds:
    key = (id(limits), dt_s)
    cached = _bounds_cache.get(key)
    if cached is not None and cached[0] is limits:
        return cached[1]
    with np.errstate(invalid="ignore", over="ignore"):  # inf and NaN are replaced below
        bounds = _derive_bounds(limits, dt_s)
    if len(_bounds_cache) > 64:  # a handful of (limits, dt) pairs in any real run
        _bounds_cache.clear()
    _bounds_cache[key] = (limits, bounds)
    return bounds


def _derive_bounds(limits: JointLimits, dt_s: float) -> _Bounds:
    a_step = limits.acceleration * dt_s * dt_s
    v_step = limits.velocity * dt_s
    finite = np.isfinite(a_step)
    a_finite = np.where(finite, a_step, 0.0)
    inv_a = np.divide(1.0, a_step, out=np.zeros_like(a_step), where=finite)
    # The furthest any step the rate check lets through (up to v_step + _EPS) can carry a
    # joint, braking included: with a tiny a_step, the tolerance alone brakes a long way.
    top = v_step + _EPS
    m = np.floor(top * inv_a)
    margin = np.where(np.isfinite(v_step), top + m * top - a_finite * m * (m + 1) / 2, np.inf)
    # A few ulps wider, so that rounding never skips a braking bound that binds; and no margin
    # at all (∞) where v_step²/a_step overflows into NaN.
    margin = np.where(np.isnan(margin), np.inf, margin * (1.0 + _ROUNDING_ULPS * _ULP))
    arm = limits.arm_mask
    lower = np.where(arm, limits.lower + margin, limits.lower)
    upper = np.where(arm, limits.upper - margin, limits.upper)
    mid, half = _band(lower, upper)
    rows = np.stack([np.where(arm, v_step + _EPS, np.inf), np.where(arm, a_step + _EPS, np.inf),
                     half])
    return _Bounds(
        lower=limits.lower - _EPS, upper=limits.upper + _EPS, v_step=v_step, a_step=a_step,
        a_finite=a_finite, inv_a=inv_a, arm=arm, margin=margin, mid=mid, kind_bounds=rows,
    )


def _band(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre and half-width of ``[lower, upper]``: (0, ∞) where both ends are unbounded, a
    −∞ half-width where the band is one-sided or empty (such a joint takes the exact check).

    ``|x − mid| <= half`` in floating point means ``lower <= x <= upper`` only to within a few
    units in the last place of the larger bound, so the band is narrowed by that much: with
    limits like ±1e300 it must not admit what the limits refuse.
    """
    unbounded = np.isneginf(lower) & np.isposinf(upper)
    rounding = _ROUNDING_ULPS * _ULP * np.maximum(np.abs(lower), np.abs(upper))
    mid = np.where(unbounded, 0.0, (lower + upper) / 2)
    half = np.where(unbounded, np.inf, (upper - lower) / 2 - rounding)
    usable = unbounded | (np.isfinite(mid) & (half >= 0))
    return np.where(usable, mid, 0.0), np.where(usable, half, -np.inf)


def project(
    actions: np.ndarray, reference: Reference, dt_s: float, limits: JointLimits
) -> Projection:
    """Project ``actions`` (H×D) into the limits, starting from ``reference``.

    Both must be finite: admission refuses a non-finite chunk before planning, and the core
    keeps its last valid state when a measurement is not finite.
    """
    bounds = _bounds(limits, dt_s)
    fast = _fast(actions, reference, bounds, limits)
    if isinstance(fast, Projection):
        return fast
    return _exact(actions, fast, reference, bounds, limits)


def project_fast(
    actions: np.ndarray, reference: Reference, dt_s: float, limits: JointLimits
) -> Projection | None:
    """The projection when the proposal already satisfies every bound (nothing to move, a few
    vectorized checks); None when some joint needs the exact, sequential projection, which
    :func:`project` does (a caller can run that where it does not delay a control tick)."""
    fast = _fast(actions, reference, _bounds(limits, dt_s), limits)
    return fast if isinstance(fast, Projection) else None


def _fast(
    actions: np.ndarray, reference: Reference, bounds: _Bounds, limits: JointLimits
) -> Projection | np.ndarray:
    """The unchanged proposal when it is feasible as it stands, else its H×D violations."""
    if actions.ndim != 2 or actions.shape[1] != limits.dim:
        raise ValueError(f"actions of shape {actions.shape} for {limits.dim} limits")
    if not actions.size:
        return Projection(actions, np.zeros(0), True)
    band, zeros = bounds.band(actions.shape[0])
    if _inside(actions, reference, bounds.mid, band):
        return Projection(actions, zeros, True)
    violating = _violations(actions, reference, bounds)
    if not np.count_nonzero(violating):
        return Projection(actions, zeros, True)
    return violating


def _exact(
    actions: np.ndarray, violating: np.ndarray, reference: Reference, bounds: _Bounds,
    limits: JointLimits,
) -> Projection:
    projected = actions.copy()
    recoverable = True
    for joint in np.flatnonzero(violating.any(axis=0)):
        if limits.gripper_index == joint:
            np.clip(projected[:, joint], limits.lower[joint], limits.upper[joint],
                    out=projected[:, joint])
            continue
        flags = violating[:, joint]
        first = int(np.argmax(flags))
        last = int(flags.shape[0] - 1 - np.argmax(flags[::-1]))
        recoverable &= _project_joint(projected, joint, (first, last), reference, bounds,
                                      limits)
    distances = np.abs(projected - actions).max(axis=1)
    projected.setflags(write=False)
    return Projection(projected, distances, recoverable, float(distances.max()))


def _inside(actions: np.ndarray, ref: Reference, mid: np.ndarray, band: np.ndarray) -> bool:
    """Does the proposal already satisfy every bound, far from its position limits? (the common
    case, and the gripper inside its limits)

    One pass of a few numpy calls, because each costs microseconds on arrays this small: the
    steps, the changes of step and the distances from the band's centre are written into one
    3H×D buffer and compared with their bounds at once. NaN compares false, so it is never
    admitted here. A proposal that fails this check may still be admissible; the exact check
    decides.
    """
    horizon = actions.shape[0]
    work = np.empty(band.shape)
    steps, changes = work[:horizon], work[horizon:2 * horizon]
    np.subtract(actions[0], ref.q, out=steps[0])
    np.subtract(actions[1:], actions[:-1], out=steps[1:])
    np.subtract(steps[0], ref.step, out=changes[0])
    np.subtract(steps[1:], steps[:-1], out=changes[1:])
    np.subtract(actions, mid, out=work[2 * horizon:])
    np.abs(work, out=work)
    return np.count_nonzero(np.less_equal(work, band)) == work.size


def _steps(actions: np.ndarray, ref: Reference) -> tuple[np.ndarray, np.ndarray]:
    """Each action's step from the one before, and each step's change from the one before."""
    steps = np.empty_like(actions)
    steps[0] = actions[0] - ref.q
    np.subtract(actions[1:], actions[:-1], out=steps[1:])
    changes = np.empty_like(actions)
    changes[0] = steps[0] - ref.step
    np.subtract(steps[1:], steps[:-1], out=changes[1:])
    return steps, changes


def _reach(steps: np.ndarray, b: _Bounds) -> np.ndarray:
    """Signed braking reach of every step (0 for unbounded acceleration)."""
    s = np.abs(steps)
    m = np.floor(s * b.inv_a)
    return np.copysign(m * s - b.a_finite * m * (m + 1.0) * 0.5, steps)


def _violations(actions: np.ndarray, ref: Reference, b: _Bounds) -> np.ndarray:
    """Boolean H×D: which entries break a bound, checked on the proposal as it stands.

    Finite but astronomical actions (1e300 rad) overflow into inf in the braking reach; inf
    is past every bound, which is the right answer, so the overflow is not worth a warning.
    """
    out = (actions < b.lower) | (actions > b.upper)
    with np.errstate(over="ignore", invalid="ignore"):
        steps, changes = _steps(actions, ref)
        ahead = actions + _reach(steps, b)
    rate = (np.abs(steps) > b.v_step + _EPS) | (np.abs(changes) > b.a_step + _EPS)
    rate |= (ahead > b.upper) | (ahead < b.lower)
    out[:, b.arm] |= rate[:, b.arm]
    return out


def _project_joint(
    projected: np.ndarray, joint: int, violations: tuple[int, int], ref: Reference,
    bounds: _Bounds, limits: JointLimits,
) -> bool:
    """Exact sequential projection of one joint from its first violating row on; False if the
    start cannot be continued inside the limits.

    Once the projected joint is back on the proposal (same position, same step) after the last
    row that violated anything, the rest of the proposal is feasible as it stands and is left
    untouched: a chunk that only needs a ramp-up from rest costs a few rows, not the horizon.
    The braking bound is worked out only within ``margin`` of a limit: further away it is
    larger than the velocity bound (``max_step_toward(margin) > v_step``), so it cannot bind.
    """
    first, last = violations
    lo, hi = float(limits.lower[joint]), float(limits.upper[joint])
    vmax, acc = float(bounds.v_step[joint]), float(bounds.a_step[joint])
    near = float(bounds.margin[joint])
    column = projected[:, joint]
    original = column.tolist()  # plain floats: one conversion, not one numpy scalar per row
    values = list(original)
    start = float(ref.q[joint])
    if first == 0:
        p, s = start, float(ref.step[joint])
    else:
        p = values[first - 1]
        s = p - (values[first - 2] if first >= 2 else start)
    recoverable = True
    for row in range(first, len(values)):
        if row > last and _on_proposal(p, s, original, row, start):
            break
        low, high = max(-vmax, s - acc), min(vmax, s + acc)
        if p - lo < near:
            low = max(low, -max_step_toward(p - lo, acc))
        if hi - p < near:
            high = min(high, max_step_toward(hi - p, acc))
        if low > high + _EPS:
            # The reference itself cannot be continued inside the limits: brake as hard as
            # allowed and let the caller refuse the chunk.
            recoverable = False
            low = high = max(s - acc, min(s + acc, 0.0))
        s = min(max(values[row] - p, low), high)
        p = min(max(p + s, lo), hi)
        values[row] = p
    column[first:] = values[first:]
    return recoverable


def _on_proposal(p: float, s: float, original: list[float], row: int, start: float) -> bool:
    """Is the projected state (position ``p``, step ``s``) the proposal's own before ``row``?"""
    before = original[row - 1]
    step = before - (original[row - 2] if row >= 2 else start)
    return abs(p - before) <= 1e-12 and abs(s - step) <= 1e-12

