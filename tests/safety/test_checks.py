"""The monitor's own limit checks: plain comparisons against the manifest's numbers."""

from __future__ import annotations

import math
from pathlib import Path

from kernel.safety.checks import Breach, Limits, Sample, breaches
from kernel.safety.settings import SafetySettings
from kernel.safety.view import read_view

MANIFESTS = Path(__file__).resolve().parents[2] / "manifests"
LIMITS = Limits(lower=(-1.0, -2.0), upper=(1.0, 2.0), velocity=(1.0, 2.0), max_force_n=50.0,
                position_margin=0.02, velocity_margin=0.1)


def _kinds(sample: Sample) -> list[Breach]:
    return [finding.breach for finding in breaches(sample, LIMITS)]


def test_inside_every_limit_and_its_margin_is_no_breach() -> None:
    assert _kinds(Sample(q=(1.019, -2.019), qd=(1.099, -2.199), force_n=50.0)) == []


def test_each_limit_is_its_own_breach_and_names_the_joint() -> None:
    found = breaches(Sample(q=(1.03, 0.0), qd=(0.0, -2.3), force_n=50.5), LIMITS)
    assert [f.breach for f in found] == [Breach.POSITION, Breach.VELOCITY, Breach.FORCE]
    assert str(found[0]) == "position: joint 0 at 1.0300 rad, limits [-1, 1]"
    assert str(found[1]) == "velocity: joint 1 at -2.300 rad/s, limit 2 rad/s"
    assert str(found[2]) == "force: wrist force 50.5 N > 50 N"


def test_a_value_that_is_not_finite_is_a_breach() -> None:
    assert _kinds(Sample(q=(math.nan, 0.0), qd=(0.0, math.inf), force_n=math.nan)) == [
        Breach.POSITION, Breach.VELOCITY, Breach.FORCE]


def test_a_device_with_another_number_of_joints_is_not_this_arm() -> None:
    assert _kinds(Sample(q=(0.0,) * 3, qd=(0.0,) * 3, force_n=None)) == [Breach.DEVICE_LOST]


def test_no_wrist_sensor_no_force_check() -> None:
    assert _kinds(Sample(q=(0.0, 0.0), qd=(0.0, 0.0), force_n=None)) == []


def test_limits_are_the_manifests_arm_joints() -> None:
    view = read_view(MANIFESTS / "sim-ur5e-rtde.toml")
    limits = Limits.of(view.limits, SafetySettings(max_wrist_force_n=80.0))
    assert limits.lower == (-6.2832, -6.2832, -3.1416, -6.2832, -6.2832, -6.2832)
    assert limits.velocity == (3.1416,) * 6 and limits.max_force_n == 80.0
