"""Projection judged by an independent oracle (tests/core/projection_oracle.py).

Every bound is pushed through ``project()`` at 0.99× and 1.01× of its limit: the first must
pass unchanged, the second must be projected (or refused as not recoverable) so that the oracle
holds. Then hypothesis draws limits, spacings, horizons, references and proposals, and the
oracle judges what ``project()`` returns. Nothing here calls the module's own checks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from assurance.limits import JointLimits
from assurance.projection import Projection, Reference, project
from tests.core.projection_oracle import (
    bounds_broken,
    can_continue,
    stopping_distance,
    stopping_position,
    violations,
)

INF = float("inf")
UNCHANGED = 1e-12
"""A feasible proposal comes back as it was, to within rounding."""

# (velocity rad/s, acceleration rad/s², action spacing s): a UR-like joint on a 2 ms grid, the
# policy's 10 ms grid, a slow joint on a coarse grid, a stiff one.
SCALES = [(1.0, 10.0, 0.01), (3.14, 40.0, 0.002), (0.2, 0.5, 0.1), (2.0, 100.0, 0.005)]
FACTORS = [0.99, 1.01]


@dataclass(frozen=True)
class Case:
    actions: np.ndarray
    ref_q: np.ndarray
    ref_step: np.ndarray
    dt: float
    limits: JointLimits

    def project(self) -> Projection:
        return project(self.actions, Reference(self.ref_q, self.ref_step), self.dt, self.limits)

    def broken(self, actions: np.ndarray | None = None) -> set[str]:
        chosen = self.actions if actions is None else actions
        return bounds_broken(chosen, self.ref_q, self.ref_step, self.dt, self.limits)


def one_joint(lower: float, upper: float, velocity: float, acceleration: float) -> JointLimits:
    return JointLimits(np.array([lower]), np.array([upper]), np.array([velocity]),
                       np.array([acceleration]))


def assert_judged(case: Case, factor: float, bound: str) -> None:
    """0.99×: only feasible input, returned unchanged. 1.01×: input breaks exactly ``bound``,
    and the output is either projected into every bound, or refused as not recoverable from a
    reference that the oracle agrees cannot be continued."""
    result = case.project()
    if factor < 1:
        assert case.broken() == set()
        assert result.recoverable
        assert result.max_distance <= UNCHANGED
        np.testing.assert_allclose(result.actions, case.actions, rtol=0, atol=UNCHANGED)
        return
    assert case.broken() == {bound}
    if not result.recoverable:
        assert not can_continue(case.ref_q, case.ref_step, case.dt, case.limits)
        return
    assert result.max_distance > 0
    assert case.broken(result.actions) == set(), violations(
        result.actions, case.ref_q, case.ref_step, case.dt, case.limits)


# --- each bound at 0.99× and 1.01× ---------------------------------------------------------------


@pytest.mark.parametrize("factor", FACTORS)
@pytest.mark.parametrize(("lower", "upper"), [(-1.0, 1.0), (0.2, 1.3), (-3.14, -0.5)])
@pytest.mark.parametrize("side", [1, -1])
def test_position_bound(factor: float, lower: float, upper: float, side: int) -> None:
    """The rates are unbounded: only the position limit can bind."""
    centre, half = (lower + upper) / 2, (upper - lower) / 2
    target = centre + side * factor * half
    case = Case(np.array([[centre], [target], [target]]), np.array([centre]), np.zeros(1), 0.01,
                one_joint(lower, upper, INF, INF))
    assert_judged(case, factor, "position")


@pytest.mark.parametrize("factor", FACTORS)
@pytest.mark.parametrize(("velocity", "acceleration", "dt"), SCALES)
@pytest.mark.parametrize("side", [1, -1])
@pytest.mark.parametrize("bounded_acceleration", [False, True])
def test_velocity_bound(factor: float, velocity: float, acceleration: float, dt: float,
                        side: int, bounded_acceleration: bool) -> None:
    """Cruising at a constant step: no change of step, no position limit to brake for. With a
    bounded acceleration the reference's own 1.01× step may be too fast to slow down from in
    one period: then "not recoverable" is the right answer."""
    step = side * factor * velocity * dt
    rows = 12
    case = Case(step * np.arange(1, rows + 1, dtype=float)[:, None], np.zeros(1),
                np.array([step]), dt,
                one_joint(-INF, INF, velocity, acceleration if bounded_acceleration else INF))
    assert_judged(case, factor, "velocity")


@pytest.mark.parametrize("factor", FACTORS)
@pytest.mark.parametrize(("velocity", "acceleration", "dt"), SCALES)
@pytest.mark.parametrize("side", [1, -1])
@pytest.mark.parametrize("moving", [False, True])
def test_acceleration_bound(factor: float, velocity: float, acceleration: float, dt: float,
                            side: int, moving: bool) -> None:
    """Speeding up (from rest or from cruise) at a constant change of step, well below the
    velocity limit, with no position limit."""
    change = side * factor * acceleration * dt * dt
    start = -side * 0.5 * velocity * dt if moving else 0.0
    rows = 3
    steps = start + change * np.arange(1, rows + 1, dtype=float)
    assert np.all(np.abs(steps) < velocity * dt)
    case = Case(np.cumsum(steps)[:, None], np.zeros(1), np.array([start]), dt,
                one_joint(-INF, INF, velocity, acceleration))
    assert_judged(case, factor, "acceleration")


@pytest.mark.parametrize("factor", FACTORS)
@pytest.mark.parametrize(("velocity", "acceleration", "dt"), SCALES)
@pytest.mark.parametrize("side", [1, -1])
@pytest.mark.parametrize("speed", [0.3, 1.0])
def test_braking_bound(factor: float, velocity: float, acceleration: float, dt: float,
                       side: int, speed: float) -> None:
    """Cruising toward a limit and ending short of it, with a stopping distance (braking at
    the limit) of 0.99× / 1.01× the room left after the last setpoint. Every setpoint is
    inside the limits, every step and change of step too: only braking can bind."""
    step = side * speed * velocity * dt
    rows = 6
    actions = step * np.arange(1, rows + 1, dtype=float)[:, None]
    last = float(actions[-1, 0])
    room = stopping_distance(step, acceleration * dt * dt) / factor
    near, far = last + side * room, -side * 100.0
    lower, upper = min(near, far), max(near, far)
    case = Case(actions, np.zeros(1), np.array([step]), dt,
                one_joint(lower, upper, velocity, acceleration))
    assert_judged(case, factor, "braking")


@pytest.mark.parametrize("factor", FACTORS)
@pytest.mark.parametrize("bound", ["velocity", "acceleration"])
def test_one_joint_at_a_bound_among_others_at_rest(factor: float, bound: str) -> None:
    """Four joints and a gripper; joint 2 at the bound, the others still: only joint 2 moves."""
    velocity, acceleration, dt = 3.14, 40.0, 0.01
    limits = JointLimits(np.full(5, -6.0), np.full(5, 6.0), np.full(5, velocity),
                         np.full(5, acceleration), gripper_index=4)
    rows = 5
    if bound == "velocity":
        step0 = factor * velocity * dt
        steps = np.full(rows, step0)
    else:
        step0 = 0.0
        steps = factor * acceleration * dt * dt * np.arange(1, rows + 1, dtype=float)
    actions = np.zeros((rows, 5))
    actions[:, 2] = np.cumsum(steps)
    actions[:, 4] = 0.04  # the gripper jumps open: a step, never a rate violation
    ref_step = np.zeros(5)
    ref_step[2] = step0
    case = Case(actions, np.zeros(5), ref_step, dt, limits)
    assert_judged(case, factor, bound)
    result = case.project()
    np.testing.assert_array_equal(result.actions[:, [0, 1, 3, 4]], actions[:, [0, 1, 3, 4]])


# --- properties --------------------------------------------------------------------------------


def floats(lo: float, hi: float) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


@st.composite
def limits_st(draw: st.DrawFn, dim: int) -> JointLimits:
    """Asymmetric position limits (a side may be unbounded), rates that may be unbounded."""
    lower, upper, velocity, acceleration = [], [], [], []
    for _ in range(dim):
        centre, half = draw(floats(-2.0, 2.0)), draw(floats(0.05, 3.0))
        lower.append(draw(st.just(centre - half) | st.just(-INF)))
        upper.append(draw(st.just(centre + half) | st.just(INF)))
        velocity.append(draw(floats(0.1, 5.0) | st.just(INF)))
        acceleration.append(draw(floats(0.5, 100.0) | st.just(INF)))
    grip = draw(st.none() | st.integers(0, dim - 1))
    return JointLimits(np.array(lower), np.array(upper), np.array(velocity),
                       np.array(acceleration), gripper_index=grip)


@st.composite
def cases(draw: st.DrawFn) -> Case:
    """A reference inside the limits (moving up to 1.2× the velocity limit) and a proposal:
    arbitrary rows, or a policy's motion (see :func:`motion`), maybe driven into a limit."""
    dim, rows = draw(st.integers(1, 4)), draw(st.integers(1, 12))
    limits = draw(limits_st(dim))
    dt = draw(st.sampled_from([0.002, 0.01, 0.05, 0.1]))
    lo, hi = np.maximum(limits.lower, -5.0), np.minimum(limits.upper, 5.0)
    ref_q = np.array([draw(floats(a, b)) for a, b in zip(lo, hi, strict=True)])
    v_step = np.minimum(limits.velocity * dt, 0.5)
    a_step = np.minimum(limits.acceleration * dt * dt, 0.5)
    ref_step = np.array([draw(floats(-1.2, 1.2)) * v for v in v_step])
    if draw(st.booleans()):
        actions = np.array([[draw(floats(a - 1.0, b + 1.0)) for a, b in zip(lo, hi, strict=True)]
                            for _ in range(rows)])
        return Case(actions, ref_q, ref_step, dt, limits)
    cruise = np.array([draw(floats(-1.5, 1.5)) for _ in range(dim)]) * v_step
    if draw(st.booleans()):
        ref_step = cruise  # already at speed: the proposal only has to keep it
    return Case(draw(motion(ref_q, ref_step, cruise, a_step, rows)), ref_q, ref_step, dt, limits)


@st.composite
def motion(draw: st.DrawFn, start: np.ndarray, step: np.ndarray, cruise: np.ndarray,
           a_step: np.ndarray, rows: int) -> np.ndarray:
    """What a policy might send: from ``step``, ramp toward ``cruise`` (up to 1.5× the velocity
    limit) changing the step by up to 1.3× the acceleration limit, with jitter."""
    ramp = draw(floats(0.5, 1.3)) * a_step
    q, out = start.copy(), []
    for _ in range(rows):
        jitter = np.array([draw(floats(-0.3, 0.3)) for _ in range(len(start))]) * a_step
        step = step + np.clip(cruise - step, -ramp, ramp) + jitter
        q = q + step
        out.append(q)
    return np.array(out)


@st.composite
def steady_motions(draw: st.DrawFn) -> Case:
    """Far from the position limits, each joint either cruises at 0.5–1.5× its velocity limit
    (the step changing by under half the acceleration limit) or wiggles below its velocity
    limit with changes of step at 0.5–1.3× the acceleration limit: a proposal either side of a
    rate bound, which the fast path of the projection sees first."""
    dim, rows = draw(st.integers(1, 4)), draw(st.integers(1, 12))
    dt = draw(st.sampled_from([0.002, 0.01, 0.05]))
    velocity = np.array([draw(floats(0.1, 5.0)) for _ in range(dim)])
    acceleration = np.array([draw(floats(0.5, 100.0)) for _ in range(dim)])
    v_step, a_step = velocity * dt, acceleration * dt * dt
    wide = draw(st.sampled_from([100.0, INF]))
    limits = JointLimits(np.full(dim, -wide), np.full(dim, wide), velocity, acceleration)
    steps = np.empty((rows, dim))
    for joint in range(dim):
        if draw(st.booleans()):
            cruise = draw(floats(0.5, 1.5)) * v_step[joint] * draw(st.sampled_from([1, -1]))
            jitter = [draw(floats(-0.2, 0.2)) * a_step[joint] for _ in range(rows)]
            steps[:, joint] = cruise + np.array(jitter)
        else:
            change = draw(floats(0.5, 1.3)) * a_step[joint]
            signs = np.where(np.arange(rows) % 2, -1.0, 1.0)
            base = min(0.5 * v_step[joint], 0.5 * change)
            steps[:, joint] = base + np.cumsum(signs * change) - change / 2
    ref_step = np.clip(steps[0], -v_step, v_step)  # a reference the limits can continue
    ref_q = np.zeros(dim)
    return Case(ref_q + np.cumsum(steps, axis=0), ref_q, ref_step, dt, limits)


@given(steady_motions())
def test_steady_motion_is_left_alone_exactly_when_the_oracle_admits_it(case: Case) -> None:
    result = case.project()
    assert result.recoverable
    admitted = not case.broken()
    assert (result.max_distance == 0.0) == admitted
    assert case.broken(result.actions) == set()


@given(cases())
def test_a_recoverable_projection_passes_the_oracle(case: Case) -> None:
    result = case.project()
    if result.recoverable:
        assert violations(result.actions, case.ref_q, case.ref_step, case.dt, case.limits) == []


@given(cases())
def test_not_recoverable_exactly_when_the_reference_cannot_be_continued(case: Case) -> None:
    result = case.project()
    # Away from the edge of continuability: the oracle and the projection round differently.
    nudged = [Case(case.actions, case.ref_q, case.ref_step * f, case.dt, case.limits)
              for f in (0.999, 1.001)]
    verdicts = {can_continue(c.ref_q, c.ref_step, c.dt, c.limits) for c in nudged}
    assume(len(verdicts) == 1)
    assert result.recoverable == verdicts.pop()


@given(cases())
def test_what_the_oracle_admits_comes_back_unchanged(case: Case) -> None:
    if not case.broken():
        result = case.project()
        assert result.recoverable and result.max_distance <= UNCHANGED


@given(cases())
def test_rows_before_the_first_broken_bound_are_untouched(case: Case) -> None:
    found = violations(case.actions, case.ref_q, case.ref_step, case.dt, case.limits)
    first = min((v.row for v in found), default=case.actions.shape[0])
    result = case.project()
    np.testing.assert_array_equal(result.actions[:first], case.actions[:first])


@given(cases())
def test_setpoints_stay_inside_the_position_limits_even_when_not_recoverable(
    case: Case
) -> None:
    out = case.project().actions
    assert np.all(out >= case.limits.lower - 1e-9) and np.all(out <= case.limits.upper + 1e-9)


# --- the oracle itself ---------------------------------------------------------------------------


def test_the_oracle_brakes_like_a_hand_computation() -> None:
    # a_step 1, step 3: steps 2, 1, 0 → 3 further on; step 3.5: 2.5, 1.5, 0.5 → 4.5
    assert stopping_position(0.0, 3.0, 1.0, -INF, 10.0) == 3.0
    assert stopping_position(10.0, -3.5, 1.0, -10.0, INF) == 5.5
    assert stopping_position(0.0, 0.5, 1.0, -1.0, 1.0) == 0.0
    assert stopping_position(0.0, 3.0, INF, -INF, 1.0) == 0.0
    assert stopping_position(0.0, 3.0, 1.0, -INF, 1.0) == 2.0  # past the limit: stops looking
    assert stopping_distance(-3.5, 1.0) == 4.5 and stopping_distance(3.0, INF) == 0.0


def test_the_oracle_names_each_broken_bound() -> None:
    limits = one_joint(-1.0, 1.0, 1.0, 10.0)  # on 10 ms: v_step 0.01, a_step 0.001
    at_rest = (np.zeros(1), np.zeros(1))
    assert bounds_broken(np.array([[0.0011]]), *at_rest, 0.01, limits) == {"acceleration"}
    cruise = np.array([0.0105])
    assert bounds_broken(np.array([[0.0105]]), np.zeros(1), cruise, 0.01, limits) == {
        "velocity"}
    near_edge = np.array([0.99])  # moving 0.005 per step: 0.01 more to stop, past 1.0
    assert bounds_broken(np.array([[0.995]]), near_edge, np.array([0.005]), 0.01, limits) == {
        "braking"}
    assert bounds_broken(np.array([[1.01]]), np.array([1.01]), np.zeros(1), 0.01, limits) == {
        "position"}
