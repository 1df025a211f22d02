"""An oracle for joint-space projection, written from the limits alone.

It shares nothing with ``assurance.projection``: no bounds cache, no closed-form braking reach,
no violation mask. Each bound is checked the way the contract states it (docs/contract.md §8,
Admission, "Projection"), on the chunk's own action grid of spacing ``dt``:

- position: every setpoint inside ``[lower, upper]``;
- velocity: every step (from the setpoint before it, the reference's for the first) at most
  ``v·dt``;
- acceleration: every change of step at most ``a·dt²`` (the first against the reference's step);
- braking: from every setpoint inside the position limits, moving with its step, braking at
  ``a·dt²`` per step² comes to rest inside them. That is simulated step by step, not computed
  in closed form. (A setpoint outside the limits breaks the position bound; that says it all.)

The gripper dimension is only held to its position limits. Infinite limits bound nothing.
``TOLERANCE`` is the slack the projection is allowed on every bound (it documents 1e-9): a few
ulps of rounding, orders of magnitude below any bound a test draws.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from assurance.limits import JointLimits

TOLERANCE = 1e-9
_RELATIVE = 1e-12
"""Rounding of a difference of two positions of magnitude |p|: a few ulps of |p|."""


@dataclass(frozen=True)
class Violation:
    row: int
    joint: int
    bound: str
    """``position``, ``velocity``, ``acceleration`` or ``braking``."""
    value: float
    limit: float


def _slack(*magnitudes: float) -> float:
    finite = [abs(m) for m in magnitudes if math.isfinite(m)]
    return TOLERANCE + _RELATIVE * max(finite, default=0.0)


def braking_speeds(speed: float, a_step: float) -> Iterator[float]:
    """The speeds (distance per period) of a joint braking as hard as allowed from ``speed``:
    ``a_step`` less every period, never reversing, ending at rest."""
    while speed > 0.0:
        speed = 0.0 if speed <= a_step else speed - a_step
        yield speed


def stopping_distance(step: float, a_step: float) -> float:
    """How much further a joint moving ``step`` per period travels while braking (unsigned)."""
    if math.isinf(a_step):
        return 0.0
    return sum(braking_speeds(abs(step), a_step))


def stopping_position(p: float, step: float, a_step: float, lo: float, hi: float) -> float:
    """Where a joint at ``p`` moving ``step`` per period comes to rest, braking as hard as
    allowed.

    Hardest braking is the best any continuation can do, so the state is brakeable exactly when
    this position is inside the limits. The simulation stops early once the joint has passed
    the limit it is moving toward: the answer is then "outside" whatever happens next.
    """
    if step == 0.0 or math.isinf(a_step):
        return p
    if a_step <= 0.0:  # a·dt² underflowed: this joint never stops
        return math.copysign(math.inf, step)
    direction = 1.0 if step > 0 else -1.0
    limit = hi if direction > 0 else lo
    if math.isinf(limit):
        return p  # nothing to run into
    for speed in braking_speeds(abs(step), a_step):
        p += direction * speed
        if direction * (p - limit) > _slack(limit):
            break
    return p


def violations(
    actions: np.ndarray, ref_q: np.ndarray, ref_step: np.ndarray, dt: float, limits: JointLimits
) -> list[Violation]:
    """Every bound ``actions`` (H×D) break, following the reference ``(ref_q, ref_step)``."""
    found: list[Violation] = []
    rows, dims = actions.shape
    for joint in range(dims):
        lo, hi = float(limits.lower[joint]), float(limits.upper[joint])
        v_step = float(limits.velocity[joint]) * dt
        a_step = float(limits.acceleration[joint]) * dt * dt
        is_gripper = limits.gripper_index == joint
        before, step_before = float(ref_q[joint]), float(ref_step[joint])
        for row in range(rows):
            p = float(actions[row, joint])
            inside = lo - _slack(lo) <= p <= hi + _slack(hi)
            if not inside:
                found.append(Violation(row, joint, "position", p, lo if p < lo else hi))
            step = p - before
            if not is_gripper:
                slack = _slack(p, before)
                if abs(step) > v_step + slack:
                    found.append(Violation(row, joint, "velocity", abs(step), v_step))
                if abs(step - step_before) > a_step + slack:
                    found.append(Violation(row, joint, "acceleration", abs(step - step_before),
                                           a_step))
                rest = stopping_position(p, step, a_step, lo, hi)
                if inside and not lo - _slack(lo) <= rest <= hi + _slack(hi):
                    found.append(Violation(row, joint, "braking", rest, lo if rest < lo else hi))
            before, step_before = p, step
    return found


def bounds_broken(
    actions: np.ndarray, ref_q: np.ndarray, ref_step: np.ndarray, dt: float, limits: JointLimits
) -> set[str]:
    return {v.bound for v in violations(actions, ref_q, ref_step, dt, limits)}


def can_continue(ref_q: np.ndarray, ref_step: np.ndarray, dt: float, limits: JointLimits) -> bool:
    """Can the reference state itself be continued inside the limits? Its hardest-braking
    continuation (one change of step at most ``a·dt²`` toward rest, then braking) must keep
    each step within ``v·dt`` and come to rest inside the position limits. Only meaningful for
    a reference inside its position limits (the strategies draw it there)."""
    for joint in np.flatnonzero(limits.arm_mask):
        lo, hi = float(limits.lower[joint]), float(limits.upper[joint])
        v_step = float(limits.velocity[joint]) * dt
        a_step = float(limits.acceleration[joint]) * dt * dt
        step = float(ref_step[joint])
        first = 0.0 if abs(step) <= a_step else step - math.copysign(a_step, step)
        if abs(first) > v_step + _slack(step):
            return False
        p = float(ref_q[joint]) + first
        rest = stopping_position(p, first, a_step, lo, hi)
        if not lo - _slack(lo) <= p <= hi + _slack(hi) or not (
            lo - _slack(lo) <= rest <= hi + _slack(hi)
        ):
            return False
    return True
