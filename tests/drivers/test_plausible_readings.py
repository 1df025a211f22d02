"""A driver's own record of its readings (drivers/plausible.py): the core's check, the core's
bounds, and the last plausible reading in an implausible one's place."""

from __future__ import annotations

from drivers.base import ControlConfig
from drivers.plausible import LastPlausible

PERIOD_NS = 8_000_000
CONTROL = ControlConfig(dof=2, period_ns=PERIOD_NS, q_lower=(-3.0,) * 2, q_upper=(3.0,) * 2,
                        v_max=(3.0,) * 2, a_max=(20.0,) * 2)
REST = (0.1, -0.2)
GLITCHED = (0.6, -0.2)


def _at_rest(readings: LastPlausible, periods: int = 5) -> int:
    t = 0
    for t in range(0, periods * PERIOD_NS, PERIOD_NS):
        assert readings.believed(t, REST, (0.0, 0.0)) == REST
    return t


def test_a_glitched_reading_is_replaced_by_the_last_plausible_one() -> None:
    readings = LastPlausible()
    readings.configure(CONTROL)
    t = _at_rest(readings)
    # Read every period for 0.4 s: long past the time the velocity limit needs for the step,
    # the velocities reported (none) still say the joint did not go there.
    for period in range(1, 51):
        assert readings.believed(t + period * PERIOD_NS, GLITCHED, (0.0, 0.0)) == REST
    assert readings.believed(t + 51 * PERIOD_NS, REST, (0.0, 0.0)) == REST


def test_without_acceleration_limits_positions_are_judged_by_the_velocity_limit() -> None:
    readings = LastPlausible()
    readings.configure(ControlConfig(dof=2, period_ns=PERIOD_NS, q_lower=(-3.0,) * 2,
                                     q_upper=(3.0,) * 2, v_max=(3.0,) * 2))
    t = _at_rest(readings)
    assert readings.believed(t + PERIOD_NS, GLITCHED, (0.0, 0.0)) == REST
    moved = (0.12, -0.2)  # 20 mrad in a period: 2.5 rad/s, inside the limit
    assert readings.believed(t + PERIOD_NS, moved, (9.0, 0.0)) == moved  # qd not used


def test_no_plausible_reading_yet_is_none_and_before_configure_all_are_believed() -> None:
    readings = LastPlausible()
    assert readings.believed(0, GLITCHED, (50.0, 0.0)) == GLITCHED  # no limits yet
    readings.configure(CONTROL)
    assert readings.believed(0, GLITCHED, (50.0, 0.0)) is None  # 50 rad/s: no motion
    assert readings.believed(PERIOD_NS, REST, (0.0, 0.0)) == REST
