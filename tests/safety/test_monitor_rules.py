"""Two monitor rules pinned directly (issue 15, item 14: mutants of each survived the suite).

- A reading that is not a number breaks its limit: a NaN or infinite velocity, position or
  force is a breach, never a pass.
- A new kind of breach stops the arm at once even while an earlier one persists (the arm at
  rest, so the persisting one alone would not stop it again).
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from kernel.manifest import load_manifest
from kernel.safety.checks import Breach, Limits, Sample, breaches
from kernel.safety.heartbeat import HeartbeatReceiver
from kernel.safety.settings import SafetySettings
from kernel.safety.view import read_view
from tests.safety.test_monitor import LIMITS, SETTINGS, Clock, ScriptedWatch, _monitor

NAN, INF = math.nan, math.inf
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def receiver(tmp_path: Path) -> Iterator[HeartbeatReceiver]:
    made = HeartbeatReceiver(tmp_path / "hb.sock", os.getegid(), SETTINGS.heartbeat_timeout_ns,
                             SETTINGS.closing_timeout_ns)
    yield made
    made.close()


@pytest.mark.parametrize("qd", [NAN, INF, -INF])
def test_a_velocity_that_is_not_a_number_is_a_velocity_breach(qd: float) -> None:
    found = breaches(Sample(q=(0.0,), qd=(qd,), force_n=0.0), LIMITS)
    assert [f.breach for f in found] == [Breach.VELOCITY]


@pytest.mark.parametrize("q", [NAN, INF, -INF])
def test_a_position_that_is_not_a_number_is_a_position_breach(q: float) -> None:
    found = breaches(Sample(q=(q,), qd=(0.0,), force_n=0.0), LIMITS)
    assert [f.breach for f in found] == [Breach.POSITION]


def test_a_force_that_is_not_a_number_is_a_force_breach() -> None:
    found = breaches(Sample(q=(0.0,), qd=(0.0,), force_n=NAN), LIMITS)
    assert [f.breach for f in found] == [Breach.FORCE]


def test_a_second_breach_while_the_first_persists_stops_the_arm_again(
        receiver: HeartbeatReceiver, clock: Clock) -> None:
    watch = ScriptedWatch()
    monitor = _monitor(watch, receiver, clock)
    watch.reading = Sample(q=(1.2,), qd=(0.0,), force_n=0.0)  # at rest past its limit
    monitor.check()
    assert watch.stops == 1
    clock.advance(4)
    monitor.check()
    assert watch.stops == 1  # the same breach, the arm still: no second stop
    watch.reading = Sample(q=(1.2,), qd=(0.0,), force_n=80.0)  # and now pressing too hard
    clock.advance(4)
    monitor.check()
    assert watch.stops == 2
    assert not monitor.stops[-1].repeated
    assert any(f.startswith("force") for f in monitor.stops[-1].findings)


def test_a_device_reporting_another_number_of_velocities_is_lost() -> None:
    found = breaches(Sample(q=(0.0,), qd=(0.0, 0.0), force_n=0.0), LIMITS)
    assert [f.breach for f in found] == [Breach.DEVICE_LOST]


def test_a_joint_exactly_at_its_limits_is_inside_them() -> None:
    edges = [Sample(q=(q,), qd=(qd,), force_n=50.0) for q in (-1.0, 1.0) for qd in (-1.0, 1.0)]
    assert all(breaches(sample, LIMITS) == [] for sample in edges)


def test_the_monitors_limits_are_the_manifests_arm_limits() -> None:
    manifest = load_manifest(ROOT / "manifests" / "sim-ur5e.toml")
    safety = SafetySettings(max_wrist_force_n=80.0, position_margin_rad=0.02,
                            velocity_margin=0.15)
    limits = Limits.of(read_view(manifest.path).limits, safety)  # the monitor's own reading
    core = manifest.core.limits
    arm = core.arm_mask
    assert limits.lower == tuple(core.lower[arm].tolist())
    assert limits.upper == tuple(core.upper[arm].tolist())
    assert limits.velocity == tuple(core.velocity[arm].tolist())
    assert (limits.max_force_n, limits.position_margin, limits.velocity_margin) == (
        80.0, 0.02, 0.15)
