"""ruckig wrappers: setpoint interpolation, braking to a hold, point-to-point joint moves."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from assurance.limits import JointLimits
from skills.interpolator import InterpolatorConfig, SetpointInterpolator
from skills.trajectory import MotionLimits, decelerate_to_hold, plan_joint_move

PROPERTY = settings(max_examples=30, deadline=None)
PERIOD_NS = 2_000_000
CONFIG = InterpolatorConfig(control_period_ns=PERIOD_NS)
ACTION_NS = 20_000_000
LIMITS = MotionLimits(
    lower=np.array([-6.28, -6.28, -3.14, -6.28, -6.28, -6.28]),
    upper=np.array([6.28, 6.28, 3.14, 6.28, 6.28, 6.28]),
    velocity=np.full(6, np.pi),
    acceleration=np.array([4.0, 4.0, 6.0, 8.0, 8.0, 8.0]),
    jerk=np.array([40.0, 40.0, 60.0, 80.0, 80.0, 80.0]),
)
SLACK = 1e-6  # ruckig meets its limits to floating-point precision
SETTLED = 1e-7  # ruckig reaches targets to about 1e-8 (its own position precision)


def positions(lower: float = -3.0, upper: float = 3.0) -> st.SearchStrategy[np.ndarray]:
    return st.lists(st.floats(lower, upper), min_size=6, max_size=6).map(np.array)


def run_stream(interpolator: SetpointInterpolator, targets: list[np.ndarray],
               ticks_per_target: int, extra_ticks: int = 0) -> np.ndarray:
    """Feed each target for some ticks; rows are (position, velocity, acceleration)."""
    rows = []
    schedule = [t for t in targets for _ in range(ticks_per_target)]
    schedule += [targets[-1]] * extra_ticks
    for tick, target in enumerate(schedule):
        sp = interpolator.update(target, tick * PERIOD_NS)
        rows.append(np.concatenate([sp.position, sp.velocity, sp.acceleration]))
    return np.array(rows)


@PROPERTY
@given(start=positions(), steps=st.lists(positions(-0.2, 0.2), min_size=1, max_size=12),
       ticks_per_target=st.integers(1, 15))
def test_interpolator_output_stays_inside_limits(start, steps, ticks_per_target):
    targets = list(np.clip(start + np.cumsum(steps, axis=0), LIMITS.lower, LIMITS.upper))
    rows = run_stream(SetpointInterpolator(LIMITS, start, CONFIG), targets, ticks_per_target, 50)
    q, qd, qdd = rows[:, :6], rows[:, 6:12], rows[:, 12:]
    assert np.all(np.abs(qd) <= LIMITS.velocity * (1 + SLACK))
    assert np.all(np.abs(qdd) <= LIMITS.acceleration * (1 + SLACK))
    assert np.all(q >= LIMITS.lower - SLACK) and np.all(q <= LIMITS.upper + SLACK)
    # Setpoints are consistent with their own velocity: finite differences stay in the limit.
    assert np.all(np.abs(np.diff(np.vstack([start, q]), axis=0)) / 2e-3
                  <= LIMITS.velocity * (1 + 1e-3))


@PROPERTY
@given(velocity=st.floats(2.0, 3.1), ticks_per_target=st.integers(1, 10))
def test_stream_towards_a_limit_never_crosses_it(velocity, ticks_per_target):
    upper = LIMITS.upper[0]
    step = velocity * ticks_per_target * PERIOD_NS * 1e-9
    count = int(np.ceil((upper - 5.0) / step)) + 20  # the stream ends parked on the limit
    targets = [np.array([min(upper, 5.0 + k * step)] + [0.0] * 5) for k in range(count)]
    interpolator = SetpointInterpolator(LIMITS, targets[0], CONFIG)
    rows = run_stream(interpolator, targets, ticks_per_target, 400)
    assert rows[:, 0].max() <= upper + SLACK
    assert rows[-1, 0] == pytest.approx(upper, abs=SETTLED)


@PROPERTY
@given(speeds=st.lists(st.floats(0.0, 3.0), min_size=5, max_size=40),
       ticks_per_target=st.integers(1, 15))
def test_setpoints_never_back_up_against_a_monotonic_stream(speeds, ticks_per_target):
    # However fast the stream starts, the interpolator must not back up for a run-up. It may
    # only move backwards once it has reached the current target (a jerk-limited joint that
    # arrives with speed cannot stop on the spot when the stream stops, and settles back).
    dt = ticks_per_target * PERIOD_NS * 1e-9
    path = np.cumsum([0.0, *(v * dt for v in speeds)])
    targets = [np.full(6, -2.0 + p) for p in path]
    interpolator = SetpointInterpolator(LIMITS, targets[0], CONFIG)
    rows = run_stream(interpolator, targets, ticks_per_target, 1000)
    current_target = np.array([targets[min(i // ticks_per_target, len(targets) - 1)][0]
                               for i in range(len(rows))])
    backwards = np.flatnonzero(np.diff(rows[:, 0]) < -1e-12) + 1
    furthest = np.maximum.accumulate(rows[:, 0])
    assert np.all(furthest[backwards - 1] >= current_target[backwards] - 1e-12)
    assert rows[:, 0].min() >= targets[0][0] - 1e-12
    assert rows[-1, 0] == pytest.approx(targets[-1][0], abs=SETTLED)


def test_steady_stream_is_followed_without_stopping():
    start = np.zeros(6)
    speed = 0.5  # rad/s on every joint, a new action every 20 ms, for 3 s
    targets = [start + speed * k * ACTION_NS * 1e-9 for k in range(1, 150)]
    ticks = ACTION_NS // PERIOD_NS
    rows = run_stream(SetpointInterpolator(LIMITS, start, CONFIG), targets, ticks)
    lag = np.array([targets[i // ticks] for i in range(len(rows))]) - rows[:, :6]
    # Passing through each target at the stream's velocity: no stop-and-go once moving, and
    # the start-up lag (jerk-limited from rest) shrinks towards one action interval.
    moving = rows[len(rows) // 4:]
    assert np.all(np.abs(moving[:, 6:12] - speed) < 0.1)
    assert np.all(np.abs(lag[-ticks:]) < speed * 2 * ACTION_NS * 1e-9)
    assert np.all(np.abs(lag[-1]) < np.abs(lag[len(rows) // 4]))


def test_stream_that_stops_settles_exactly_on_the_last_target():
    start = np.zeros(6)
    targets = [start + 0.5 * k * ACTION_NS * 1e-9 for k in range(1, 20)]
    rows = run_stream(SetpointInterpolator(LIMITS, start, CONFIG), targets, 10, extra_ticks=400)
    np.testing.assert_allclose(rows[-1, :6], targets[-1], atol=SETTLED)
    np.testing.assert_allclose(rows[-1, 6:], 0.0, atol=SETTLED)


def test_interpolator_rejects_bad_input_and_keeps_its_state():
    interpolator = SetpointInterpolator(LIMITS, np.zeros(6), CONFIG)
    first = interpolator.update(np.full(6, 0.1), 10 * PERIOD_NS)
    for bad, match in (
        (np.full(6, 7.0), "not inside"),
        (np.array([np.nan] * 6), "not inside"),
        (np.zeros(5), "needs 6 values"),
    ):
        with pytest.raises(ValueError, match=match):
            interpolator.update(bad, 11 * PERIOD_NS)
        assert interpolator.setpoint is first
    with pytest.raises(ValueError, match="backwards"):
        interpolator.update(np.full(6, 0.1), 9 * PERIOD_NS)
    assert interpolator.update(np.full(6, 0.1), 11 * PERIOD_NS).t_ns == 12 * PERIOD_NS
    with pytest.raises(ValueError, match="positive"):
        InterpolatorConfig(control_period_ns=0)


@PROPERTY
@given(q=positions(), unit_velocity=st.lists(st.floats(-1, 1), min_size=6, max_size=6),
       unit_acceleration=st.lists(st.floats(-1, 1), min_size=6, max_size=6))
def test_decelerate_to_hold_ends_at_rest(q, unit_velocity, unit_acceleration):
    qd = np.array(unit_velocity) * LIMITS.velocity
    qdd = np.array(unit_acceleration) * LIMITS.acceleration
    stop = decelerate_to_hold(q, qd, LIMITS, qdd)
    end = stop.sample(stop.duration)
    np.testing.assert_allclose(end.velocity, 0.0, atol=1e-9)
    np.testing.assert_allclose(end.acceleration, 0.0, atol=1e-9)
    np.testing.assert_allclose(stop.sample(0.0).velocity, qd, atol=1e-9)
    # Braking at the limits: never harder than allowed, never longer than a crude bound.
    times = np.linspace(0.0, stop.duration, 50)
    accelerations = np.array([stop.sample(t).acceleration for t in times])
    assert np.all(np.abs(accelerations) <= LIMITS.acceleration * (1 + SLACK))
    # Crude upper bound: ramp the acceleration to zero, then brake from the speed reached.
    a, j = LIMITS.acceleration, LIMITS.jerk
    speed = np.abs(qd) + qdd**2 / (2 * j)
    assert stop.duration <= np.max(np.abs(qdd) / j + speed / a + a / j) + 1e-9
    assert np.all(stop.position_min <= end.position + 1e-9)
    assert np.all(end.position <= stop.position_max + 1e-9)


def test_decelerate_from_rest_is_immediate_and_bad_input_is_rejected():
    assert decelerate_to_hold(np.ones(6), np.zeros(6), LIMITS).duration == pytest.approx(0.0)
    with pytest.raises(ValueError, match="not finite"):
        decelerate_to_hold(np.zeros(6), np.array([np.inf] + [0.0] * 5), LIMITS)
    with pytest.raises(ValueError, match="needs 6 values"):
        decelerate_to_hold(np.zeros(6), np.zeros(3), LIMITS)


@PROPERTY
@given(q0=positions(), q1=positions())
def test_joint_move_goes_from_start_to_goal_within_limits(q0, q1):
    move = plan_joint_move(q0, q1, LIMITS)
    np.testing.assert_allclose(move.sample(0.0).position, q0, atol=1e-12)
    np.testing.assert_allclose(move.sample(move.duration).position, q1, atol=1e-9)
    np.testing.assert_allclose(move.sample(move.duration + 5.0).velocity, 0.0, atol=1e-9)
    np.testing.assert_allclose(move.sample(-1.0).position, q0, atol=1e-12)
    assert move.within(LIMITS)
    assert move.duration_ns >= int(move.duration * 1e9)
    samples = [move.sample(t) for t in np.linspace(0.0, move.duration, 40)]
    assert all(np.all(np.abs(s.velocity) <= LIMITS.velocity * (1 + SLACK)) for s in samples)
    # Phase-synchronised: every joint is the same fraction of the way at every instant.
    mid = move.sample(move.duration / 3).position
    moving = np.abs(q1 - q0) > 1e-3
    fractions = (mid - q0)[moving] / (q1 - q0)[moving]
    assert fractions.size == 0 or np.ptp(fractions) < 1e-6


def test_joint_move_rejects_bad_input():
    with pytest.raises(ValueError, match=r"move goal\[2\]"):
        plan_joint_move(np.zeros(6), np.array([0, 0, 3.5, 0, 0, 0]), LIMITS)
    with pytest.raises(ValueError, match="move start"):
        plan_joint_move(np.array([np.nan] * 6), np.zeros(6), LIMITS)
    with pytest.raises(ValueError, match="sample"):
        plan_joint_move(np.zeros(6), np.ones(6), LIMITS).sample(float("nan"))
    assert plan_joint_move(np.ones(6), np.ones(6), LIMITS).duration == pytest.approx(0.0)


def test_motion_limits_validation_and_conversion():
    with pytest.raises(ValueError, match="positive"):
        MotionLimits.uniform(6, 1.0, 1.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="shape"):
        MotionLimits(np.zeros(6), np.ones(5), np.ones(6), np.ones(6), np.ones(6))
    with pytest.raises(ValueError, match="exceeds"):
        MotionLimits.uniform(6, -1.0, 1.0, 1.0, 1.0)
    projection = JointLimits.uniform(7, 3.0, 2.0, 5.0, gripper_index=6)
    motion = MotionLimits.from_joint_limits(projection, jerk=50.0)
    assert motion.dof == 6
    np.testing.assert_allclose(motion.jerk, 50.0)
    np.testing.assert_allclose(motion.upper, 3.0)
    assert motion.contains(np.zeros(6)) and not motion.contains(np.full(6, 3.1))
