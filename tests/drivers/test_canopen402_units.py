"""Counts ↔ radians: round trips, and the driver's and the emulator's conversions agree."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.canopen402.units import INT32_MAX, JointScale
from stubs.cia402_drive.drive import Encoder

counts_per_rev = st.integers(min_value=1_000, max_value=2**24)
direction = st.sampled_from((1, -1))
offset = st.integers(min_value=-(2**24), max_value=2**24)
angle = st.floats(min_value=-20.0, max_value=20.0, allow_nan=False)
"""±20 rad: a few turns either way, within INTEGER32 for every resolution drawn here."""


@given(counts_per_rev, direction, offset, angle)
def test_radians_to_counts_and_back_within_half_a_count(cpr: int, d: int, off: int,
                                                        q: float) -> None:
    scale = JointScale(cpr, d, off)
    assert abs(scale.to_rad(scale.to_counts(q)) - q) <= math.pi / cpr + 1e-12


@given(counts_per_rev, direction, offset, st.integers(min_value=-(2**28), max_value=2**28))
def test_counts_to_radians_and_back_is_exact(cpr: int, d: int, off: int, counts: int) -> None:
    scale = JointScale(cpr, d, off)
    assert scale.to_counts(scale.to_rad(counts)) == counts


@given(counts_per_rev, direction, offset, angle)
def test_driver_and_emulator_conversions_agree(cpr: int, d: int, off: int, q: float) -> None:
    assert JointScale(cpr, d, off).to_counts(q) == Encoder(cpr, d, off).counts(q)
    assert JointScale(cpr, d, off).to_rad(12345) == pytest.approx(Encoder(cpr, d, off).rad(12345))


@given(counts_per_rev, direction, st.integers(min_value=-(10**6), max_value=10**6))
def test_velocity_follows_the_joint_direction(cpr: int, d: int, counts_per_s: int) -> None:
    rad_per_s = JointScale(cpr, d).velocity_to_rad(counts_per_s)
    assert rad_per_s == pytest.approx(d * counts_per_s * 2 * math.pi / cpr)


def test_torque_is_per_mille_of_rated_torque_times_gear() -> None:
    scale = JointScale(2**20, direction=-1, gear_ratio=100.0)
    assert scale.torque_to_nm(500, rated_torque_mnm=1500) == pytest.approx(-75.0)


def test_angle_beyond_integer32_is_refused() -> None:
    scale = JointScale(2**23)
    with pytest.raises(ValueError, match="INTEGER32"):
        scale.to_counts((INT32_MAX + 10) * 2 * math.pi / 2**23)
