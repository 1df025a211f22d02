"""The monitor's limit checks at their exact bounds, and the limits it takes from the manifest
(mutants of each survived the suite: a bound read as strict, a sample whose velocities do not
match the arm's joints passed on, the upper limits and the margins not taken over). A sample
with the right number of positions but not of velocities was reported as "the device reports
2 joints, the manifest has 2"."""

from __future__ import annotations

import math

import pytest

from kernel.manifest_tables import RobotLimits
from kernel.safety.checks import Breach, Limits, Sample, breaches
from kernel.safety.settings import SafetySettings

# Binary fractions: the bounds with their margins (±1.5 rad, 2.5 rad/s) are exact floats.
LIMITS = Limits(lower=(-1.0, -1.0), upper=(1.0, 1.0), velocity=(2.0, 2.0), max_force_n=50.0,
                position_margin=0.5, velocity_margin=0.25)


def _kinds(q: tuple[float, ...], qd: tuple[float, ...], force_n: float | None = 0.0,
           ) -> list[Breach]:
    return [finding.breach for finding in breaches(Sample(q, qd, force_n), LIMITS)]


def test_a_reading_at_a_bound_with_its_margin_is_inside() -> None:
    assert _kinds((1.5, -1.5), (2.5, -2.5), 50.0) == []


@pytest.mark.parametrize(("q", "qd", "force_n", "kind"), [
    ((math.nextafter(1.5, 2.0), 0.0), (0.0, 0.0), 0.0, Breach.POSITION),
    ((0.0, math.nextafter(-1.5, -2.0)), (0.0, 0.0), 0.0, Breach.POSITION),
    ((0.0, 0.0), (math.nextafter(2.5, 3.0), 0.0), 0.0, Breach.VELOCITY),
    ((0.0, 0.0), (0.0, math.nextafter(-2.5, -3.0)), 0.0, Breach.VELOCITY),
    ((0.0, 0.0), (0.0, 0.0), math.nextafter(50.0, 51.0), Breach.FORCE),
])
def test_the_least_step_past_a_bound_is_a_breach(q: tuple[float, ...], qd: tuple[float, ...],
                                                 force_n: float, kind: Breach) -> None:
    assert _kinds(q, qd, force_n) == [kind]


@pytest.mark.parametrize(("q", "qd"), [((0.0, 0.0), (0.0,)), ((0.0, 0.0), (0.0, 0.0, 9.0)),
                                       ((0.0,), (0.0, 0.0))])
def test_positions_or_velocities_for_another_arm_are_a_lost_device(
        q: tuple[float, ...], qd: tuple[float, ...]) -> None:
    found = breaches(Sample(q, qd, None), LIMITS)
    assert [(f.breach, f.detail) for f in found] == [
        (Breach.DEVICE_LOST,
         f"the device reports {len(q)} positions and {len(qd)} velocities, the manifest has 2 "
         f"joints")]


def test_the_limits_are_the_manifests_arm_joints_and_the_monitors_margins() -> None:
    robot = RobotLimits(lower=(-1.0, -2.0, 0.0), upper=(1.0, 2.0, 0.08),
                        velocity=(3.0, 4.0, 0.5), acceleration=(9.0, 9.0, 9.0),
                        gripper_index=2, gripper_event_threshold=0.001)
    safety = SafetySettings(position_margin_rad=0.03, velocity_margin=0.2, max_wrist_force_n=70.0)
    assert Limits.of(robot, safety) == Limits(
        lower=(-1.0, -2.0), upper=(1.0, 2.0), velocity=(3.0, 4.0), max_force_n=70.0,
        position_margin=0.03, velocity_margin=0.2)
