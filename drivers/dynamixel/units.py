"""Conversions between control-table counts and joint SI units, with per-joint calibration.

A servo's shaft angle is ``theta = (ticks - 2048) * 2π / 4096``. The joint angle is
``q = direction * (theta - offset)``: ``offset`` is the shaft angle at which the joint reads
zero, ``direction`` (+1/-1) flips joints mounted the other way round. The inverse is
``theta = direction * q + offset`` because ``direction`` is its own inverse.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from drivers.dynamixel.tables import CENTRE_TICK, TICKS_PER_REV, VELOCITY_UNIT_RPM

RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_REV
RAD_S_PER_VELOCITY_UNIT = VELOCITY_UNIT_RPM * 2.0 * math.pi / 60.0


def to_signed(value: int, size: int) -> int:
    """Two's complement of an unsigned ``size``-byte value (GroupSyncRead.getData is unsigned)."""
    bits = 8 * size
    value &= (1 << bits) - 1
    return value - (1 << bits) if value >> (bits - 1) else value


def to_unsigned(value: int, size: int) -> int:
    """The ``size``-byte pattern of a signed value, as the SDK's byte helpers expect."""
    return value & ((1 << (8 * size)) - 1)


def le_bytes(value: int, size: int) -> list[int]:
    """Little-endian bytes of a signed value (GroupSyncWrite.addParam takes a list of ints)."""
    return list(to_unsigned(value, size).to_bytes(size, "little"))


def ticks_to_theta(ticks: int) -> float:
    return (ticks - CENTRE_TICK) * RAD_PER_TICK


def theta_to_ticks(theta: float) -> int:
    return round(theta / RAD_PER_TICK) + CENTRE_TICK


@dataclass(frozen=True, slots=True)
class JointCalibration:
    offsets: tuple[float, ...]
    directions: tuple[int, ...]
    current_unit_a: float
    """Amperes per Present Current count (2.69 mA on XM430/XM540, 1 mA on XL330)."""
    torque_per_amp: float
    """N·m per ampere at the output shaft; the servo has no torque sensor, so this is a model."""

    def q_from_ticks(self, ticks: Sequence[int]) -> tuple[float, ...]:
        return tuple(
            d * (ticks_to_theta(t) - o)
            for t, o, d in zip(ticks, self.offsets, self.directions, strict=True)
        )

    def ticks_from_q(self, q: Sequence[float]) -> tuple[int, ...]:
        return tuple(
            theta_to_ticks(d * v + o) for v, o, d in zip(q, self.offsets, self.directions,
                                                         strict=True)
        )

    def qd_from_units(self, velocity: Sequence[int]) -> tuple[float, ...]:
        return tuple(d * v * RAD_S_PER_VELOCITY_UNIT
                     for v, d in zip(velocity, self.directions, strict=True))

    def effort_from_units(self, current: Sequence[int]) -> tuple[float, ...]:
        scale = self.current_unit_a * self.torque_per_amp
        return tuple(d * c * scale for c, d in zip(current, self.directions, strict=True))

    def q_range(self, tick_low: int, tick_high: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Joint-space (lower, upper) bounds of the tick range [tick_low, tick_high]."""
        ends = (self.q_from_ticks([tick_low] * len(self.offsets)),
                self.q_from_ticks([tick_high] * len(self.offsets)))
        lower = tuple(min(a, b) for a, b in zip(*ends, strict=True))
        upper = tuple(max(a, b) for a, b in zip(*ends, strict=True))
        return lower, upper


@dataclass(frozen=True, slots=True)
class GripperCalibration:
    """Gripper opening (m) ↔ servo ticks: linear between the closed and the open end.

    Unlike a joint, a gripper is calibrated by its two end stops, not by an offset: a rack or a
    linkage turns the shaft angle into an opening, and both ends are where a person measures.
    """

    open_ticks: int
    closed_ticks: int
    max_opening: float
    """Opening (m) at ``open_ticks``; the closed end is 0 m."""

    def ticks_from_opening(self, opening: float) -> int:
        """Clipped to [0, max_opening]: beyond its end stops a gripper only squeezes itself."""
        fraction = min(max(opening, 0.0), self.max_opening) / self.max_opening
        return round(self.closed_ticks + fraction * (self.open_ticks - self.closed_ticks))

    def opening_from_ticks(self, ticks: int) -> float:
        """Not clipped: a reading past an end means the calibration is off, and shows it."""
        span = self.open_ticks - self.closed_ticks
        return (ticks - self.closed_ticks) / span * self.max_opening
