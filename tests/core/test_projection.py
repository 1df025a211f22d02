"""Joint-space feasibility projection: the projected sequence is admissible, minimal, idempotent.

The oracle is ``tests/core/projection_oracle.py``, written from the limits alone: position,
velocity (step), acceleration (change of step) and braking (from every setpoint the joint can
still stop inside its limits, simulated). The fast check's own tests use the module's internals.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from assurance.limits import JointLimits
from assurance.projection import (
    Reference,
    _bounds,
    _inside,
    braking_distance,
    max_step_toward,
    project,
)
from tests.core.projection_oracle import violations

INF = float("inf")
EPS = 1e-9


@dataclass(frozen=True)
class Case:
    actions: np.ndarray
    ref: Reference
    dt: float
    limits: JointLimits


def floats(lo: float, hi: float) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


@st.composite
def limits_st(draw: st.DrawFn, dim: int, infinite: bool = True) -> JointLimits:
    def column(lo: float, hi: float) -> np.ndarray:
        value = floats(lo, hi) | st.just(INF) if infinite else floats(lo, hi)
        return np.array(draw(st.lists(value, min_size=dim, max_size=dim)))

    pos = column(0.05, 5.0)
    grip = draw(st.none() | st.integers(0, dim - 1))
    return JointLimits(-pos, pos, column(0.1, 5.0), column(0.5, 100.0), gripper_index=grip)


@st.composite
def cases(draw: st.DrawFn, infinite: bool = True) -> Case:
    dim, horizon = draw(st.integers(1, 4)), draw(st.integers(1, 10))
    limits = draw(limits_st(dim, infinite))
    dt = draw(st.sampled_from([0.002, 0.01, 0.05, 0.1]))
    span = np.minimum(limits.upper, 3.0)
    q = np.array([draw(floats(-s, s)) for s in span])
    v_step = np.minimum(limits.velocity * dt, 1.0)
    step = np.array([draw(floats(-1.2 * v, 1.2 * v)) for v in v_step])
    rows = st.lists(st.lists(floats(-6.0, 6.0), min_size=dim, max_size=dim),
                    min_size=horizon, max_size=horizon)
    return Case(np.array(draw(rows)), Reference(q, step), dt, limits)


@st.composite
def feasible_cases(draw: st.DrawFn, rate_scale: float = 0.9) -> Case:
    """Smooth motions well inside wide position limits: admissible by construction (rates
    up to ``rate_scale`` of their limits; above 1, some break the velocity or acceleration
    limit, by a little)."""
    dim, horizon = draw(st.integers(1, 4)), draw(st.integers(1, 10))
    dt = draw(st.sampled_from([0.01, 0.05]))
    vel = np.array(draw(st.lists(floats(0.1, 2.0), min_size=dim, max_size=dim)))
    acc = np.array(draw(st.lists(floats(1.0, 50.0), min_size=dim, max_size=dim)))
    limits = JointLimits(np.full(dim, -100.0), np.full(dim, 100.0), vel, acc)
    v_step, a_step = rate_scale * vel * dt, rate_scale * acc * dt * dt
    moving = np.array([draw(floats(-1.0, 1.0)) for _ in range(dim)]) * v_step
    q, step, rows = np.zeros(dim), moving, []
    for _ in range(horizon):
        change = np.array([draw(floats(-1.0, 1.0)) for _ in range(dim)]) * a_step
        step = np.clip(step + change, -v_step, v_step)
        q = q + step
        rows.append(q)
    return Case(np.array(rows), Reference(np.zeros(dim), moving), dt, limits)


@st.composite
def near_limit_cases(draw: st.DrawFn) -> Case:
    """Motions whose position limits sit just outside them (a gripper, maybe): the band of
    the fast check is narrow or empty, so both of its answers occur."""
    case = draw(feasible_cases(rate_scale=draw(st.sampled_from([0.9, 1.2]))))
    dim = case.actions.shape[1]
    room = np.array(draw(st.lists(floats(0.0, 0.02), min_size=dim, max_size=dim)))
    span = np.abs(case.actions).max(axis=0) + room + 1e-6
    grip = draw(st.none() | st.integers(0, dim - 1))
    limits = JointLimits(-span, span, case.limits.velocity, case.limits.acceleration,
                         gripper_index=grip)
    return Case(case.actions, case.ref, case.dt, limits)


def fast_check(case: Case) -> bool:
    bounds = _bounds(case.limits, case.dt)
    band, _ = bounds.band(case.actions.shape[0])
    return _inside(case.actions, case.ref, bounds.mid, band)


def admissible(actions: np.ndarray, ref: Reference, dt: float, limits: JointLimits) -> bool:
    """The oracle's verdict: no bound broken."""
    return not violations(actions, ref.q, ref.step, dt, limits)


def run(case: Case):
    return project(case.actions, case.ref, case.dt, case.limits)


# --- properties --------------------------------------------------------------------------------


@given(cases())
def test_a_recoverable_projection_passes_every_bound(case: Case) -> None:
    result = run(case)
    if result.recoverable:
        assert admissible(result.actions, case.ref, case.dt, case.limits)


@given(cases() | feasible_cases(rate_scale=1.2) | near_limit_cases())
def test_the_fast_check_never_admits_what_the_oracle_refuses(case: Case) -> None:
    if fast_check(case):
        assert admissible(case.actions, case.ref, case.dt, case.limits)


@given(feasible_cases())
def test_the_fast_check_admits_smooth_motion_far_from_the_limits(case: Case) -> None:
    assert fast_check(case)


@pytest.mark.parametrize("scale", [0.99, 1.01])
def test_the_fast_check_stops_at_each_bound(scale: float) -> None:
    """A steady step, a step change and a position, each at 99 % and 101 % of its bound."""
    dt, limits = 0.01, uniform()  # v_step 0.01, a_step 0.001, position ±1
    v_step, a_step = 1.0 * dt, 10.0 * dt * dt
    cruise = Case(np.array([[v_step * scale], [2 * v_step * scale]]),
                  Reference(np.zeros(1), np.array([v_step * scale])), dt, limits)
    kick = Case(np.array([[a_step * scale]]), at_rest(), dt, limits)
    margin = v_step + 10 * v_step - a_step * 10 * 11 / 2  # furthest reach from a full step
    edge = 1.0 - margin
    near = Case(np.array([[edge * scale]]), at_rest(edge * scale), dt, limits)
    for case in (cruise, kick, near):
        assert fast_check(case) == (scale < 1)


@pytest.mark.parametrize(("lower", "upper", "value", "grip"), [
    (-1e300, 3.0, 100.0, None),  # a huge limit standing for "unbounded": rounding in the band
    (-1e300, 3.0, 3.5, None),
    (0.0, 1e10, -4e-7, 0),  # a gripper in odd units, just below its limit
])
def test_the_fast_check_survives_limits_of_any_magnitude(
    lower: float, upper: float, value: float, grip: int | None
) -> None:
    limits = JointLimits(np.array([lower]), np.array([upper]), np.array([1.0]),
                         np.array([10.0]), gripper_index=grip)
    case = Case(np.array([[value]]), at_rest(value), 0.01, limits)
    assert not admissible(case.actions, case.ref, case.dt, case.limits)
    assert not fast_check(case)
    assert run(case).actions[0, 0] == pytest.approx(min(max(value, lower), upper))


def test_the_fast_check_allows_for_the_rate_tolerance_on_a_slow_axis() -> None:
    """With a tiny a_step, a step just inside the velocity tolerance brakes a long way: the
    band must leave room for it (found by review: 3 µrad past the limit)."""
    dt = 0.002
    limits = JointLimits(np.array([-1.0]), np.array([1.0]), np.array([1e-3]), np.array([1e-4]))
    bounds = _bounds(limits, dt)
    step = bounds.v_step[0] + 0.99e-9
    edge = bounds.mid[0] + bounds.band(1)[0][2, 0]
    case = Case(np.array([[edge]]), Reference(np.array([edge - step]), np.array([step])), dt,
                limits)
    assert fast_check(case) == admissible(case.actions, case.ref, case.dt, case.limits)


@pytest.mark.parametrize("outside", [0.0, 1e-6, 0.004])
def test_cruising_into_a_limit_brakes_in_time(outside: float) -> None:
    """Full speed toward a limit from just beyond the braking margin: the braking bound must
    take over from the first row that needs it (it is only worked out near a limit)."""
    dt, limits = 0.01, uniform()  # v_step 0.01, a_step 0.001, position ±1
    v_step = 0.01
    start = 1.0 - _bounds(limits, dt).margin[0] - outside
    ref = Reference(np.array([start]), np.array([v_step]))
    proposal = start + v_step * np.arange(1, 31, dtype=float)[:, None]
    result = project(proposal, ref, dt, limits)
    assert result.recoverable
    assert admissible(result.actions, ref, dt, limits)


def test_an_astronomical_room_gives_a_braking_bound_not_an_overflow() -> None:
    assert 0.0 < max_step_toward(1e308, 1e-6) < math.inf
    limits = JointLimits(np.array([-1e308]), np.array([1e308]), np.array([1.0]),
                         np.array([1.0]))
    result = project(np.array([[0.5]]), at_rest(), 0.01, limits)  # a jump: ramped, not raised
    assert result.actions[0, 0] == pytest.approx(1e-4)


def test_braking_still_binds_where_its_margin_overflows() -> None:
    """v_step²/a_step overflows the margin into NaN: the braking bound is then always worked
    out, and a state that cannot brake in time is still reported (found by review)."""
    limits = JointLimits(np.array([-1e8]), np.array([1e7]), np.array([1e7]), np.array([1e-297]))
    ref = Reference(np.zeros(1), np.array([1e3]))
    result = project(np.array([[1e3], [2e3], [3e3]]), ref, 0.1, limits)
    assert not result.recoverable


def test_a_chunk_of_the_wrong_width_is_an_error_not_a_broadcast() -> None:
    with pytest.raises(ValueError, match="shape"):
        project(np.zeros((2, 1)), Reference(np.zeros(6), np.zeros(6)), 0.01,
                JointLimits.uniform(6, 3.0, 2.0, 20.0))


def test_the_fast_check_refuses_nan() -> None:
    case = Case(np.array([[0.0], [np.nan]]), at_rest(), 0.01, uniform())
    assert not fast_check(case)


@given(feasible_cases())
def test_an_admissible_sequence_is_returned_unchanged(case: Case) -> None:
    assert admissible(case.actions, case.ref, case.dt, case.limits)
    result = run(case)
    np.testing.assert_array_equal(result.actions, case.actions)
    assert result.max_distance == 0.0 and result.recoverable


@given(cases())
def test_distances_are_the_max_abs_change_per_row(case: Case) -> None:
    result = run(case)
    assert result.distances.shape == (case.actions.shape[0],)
    assert (result.distances >= 0).all()
    np.testing.assert_array_equal(
        result.distances, np.abs(result.actions - case.actions).max(axis=1))
    assert result.max_distance == result.distances.max()


@given(cases())
def test_projection_is_idempotent(case: Case) -> None:
    first = run(case)
    if first.recoverable:
        again = project(first.actions, case.ref, case.dt, case.limits)
        np.testing.assert_array_equal(again.actions, first.actions)
        assert again.max_distance == 0.0


@given(cases())
def test_projected_setpoints_stay_inside_position_limits(case: Case) -> None:
    out = run(case).actions
    assert (out >= case.limits.lower - EPS).all() and (out <= case.limits.upper + EPS).all()


@given(cases())
def test_the_gripper_is_only_clipped_to_its_position_limits(case: Case) -> None:
    grip = case.limits.gripper_index
    if grip is None:
        return
    out = run(case).actions[:, grip]
    expected = np.clip(case.actions[:, grip], case.limits.lower[grip], case.limits.upper[grip])
    np.testing.assert_array_equal(out, expected)


@given(cases(infinite=False))
def test_the_gripper_does_not_influence_the_arm(case: Case) -> None:
    grip = case.limits.gripper_index
    if grip is None:
        return
    wild = case.actions.copy()
    wild[:, grip] = np.where(np.arange(wild.shape[0]) % 2, 100.0, -100.0)
    arm = case.limits.arm_mask
    np.testing.assert_array_equal(run(case).actions[:, arm],
                                  project(wild, case.ref, case.dt, case.limits).actions[:, arm])


@given(cases())
def test_rows_before_the_first_violation_are_untouched(case: Case) -> None:
    result = run(case)
    for h in range(case.actions.shape[0]):
        if not admissible(case.actions[: h + 1], case.ref, case.dt, case.limits):
            break
        assert result.distances[h] == 0.0


# --- examples ----------------------------------------------------------------------------------


def uniform(**kw: object) -> JointLimits:
    return JointLimits.uniform(1, position=1.0, velocity=1.0, acceleration=10.0, **kw)


def at_rest(q: float = 0.0) -> Reference:
    return Reference(np.array([q]), np.array([0.0]))


def test_a_jump_is_turned_into_a_ramp_within_velocity_and_acceleration() -> None:
    result = project(np.array([[0.5]] * 20), at_rest(), 0.1, uniform())
    steps = np.diff(result.actions[:, 0], prepend=0.0)
    assert result.recoverable and result.max_distance > 0
    assert np.abs(steps).max() <= 0.1 + EPS  # V = 1 rad/s * 0.1 s
    assert np.abs(np.diff(steps, prepend=0.0)).max() <= 0.1 + EPS  # A = 10 * 0.01
    assert result.actions[-1, 0] == pytest.approx(0.5)


def test_an_unbrakeable_reference_is_reported_unrecoverable() -> None:
    # 0.1 rad short of the limit at full speed (0.1 rad/step), braking only 0.01 rad/step²
    limits = JointLimits.uniform(1, position=1.0, velocity=1.0, acceleration=1.0)
    near_limit = Reference(np.array([0.9]), np.array([0.1]))
    result = project(np.array([[1.0], [1.0]]), near_limit, 0.1, limits)
    assert not result.recoverable
    assert (result.actions <= 1.0).all()


def test_infinite_limits_leave_any_finite_sequence_alone() -> None:
    limits = JointLimits(np.full(2, -INF), np.full(2, INF), np.full(2, INF), np.full(2, INF))
    actions = np.array([[0.0, 5.0], [100.0, -50.0], [-3.0, 1e6]])
    result = project(actions, Reference(np.zeros(2), np.zeros(2)), 0.01, limits)
    np.testing.assert_array_equal(result.actions, actions)
    assert result.recoverable and result.max_distance == 0.0


def test_infinite_position_with_finite_velocity_limits_steps() -> None:
    limits = JointLimits(np.array([-INF]), np.array([INF]), np.array([1.0]), np.array([INF]))
    result = project(np.array([[10.0], [20.0]]), at_rest(), 0.1, limits)
    np.testing.assert_allclose(result.actions[:, 0], [0.1, 0.2])
    assert result.recoverable


def test_the_output_is_read_only_and_the_input_untouched() -> None:
    actions = np.array([[2.0], [2.0]])
    result = project(actions, at_rest(), 0.1, uniform())
    assert not result.actions.flags.writeable
    np.testing.assert_array_equal(actions, [[2.0], [2.0]])


def test_an_empty_sequence_projects_to_nothing() -> None:
    result = project(np.zeros((0, 1)), at_rest(), 0.1, uniform())
    assert result.actions.shape == (0, 1) and result.max_distance == 0.0


@given(floats(1e-6, 50.0), floats(1e-4, 10.0))
def test_max_step_toward_inverts_the_braking_reach(room: float, acc: float) -> None:
    s = max_step_toward(room, acc)
    reach = s + float(braking_distance(np.array([s]), np.array([acc]))[0])
    assert 0 < s <= room
    assert reach == pytest.approx(room, rel=1e-9, abs=1e-12)


def test_braking_distance_examples() -> None:
    acc = np.array([1.0, 1.0, 1.0, INF])
    np.testing.assert_allclose(braking_distance(np.array([0.5, 2.0, -3.0, 5.0]), acc),
                               [0.0, 1.0, 3.0, 0.0])
    assert max_step_toward(-0.5, 1.0) == -0.5 and max_step_toward(INF, 1.0) == INF
