"""Position sensors of the emulated drives: the drive's side of the units contract.

Written independently of the driver's ``units`` module, so a wrong conversion on either side
shows up as wrong motion. Each encoder converts between counts and its axis's SI unit (radians of
a joint, metres of gripper opening); ``counts_per_unit`` and ``direction`` scale velocities and
the following-error window the same way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Encoder:
    """A joint's rotary encoder: counts per turn of the joint, its sign and its zero."""

    counts_per_rev: int
    direction: int = 1
    offset: int = 0

    def counts(self, q: float) -> int:
        return round(q * self.direction * self.counts_per_rev / (2 * math.pi)) + self.offset

    def rad(self, counts: int) -> float:
        return (counts - self.offset) * self.direction * 2 * math.pi / self.counts_per_rev

    def position(self, counts: int) -> float:
        return self.rad(counts)

    @property
    def counts_per_unit(self) -> float:
        return self.counts_per_rev / (2 * math.pi)


@dataclass(frozen=True, slots=True)
class LinearEncoder:
    """A gripper's stroke sensor: counts per metre of opening, zero when fully closed."""

    counts_per_m: float
    direction: int = 1
    """Always +1: the count grows as the fingers open (kept for the drive's velocity scaling)."""

    def counts(self, opening_m: float) -> int:
        return round(opening_m * self.counts_per_m)

    def position(self, counts: int) -> float:
        return counts / self.counts_per_m

    @property
    def counts_per_unit(self) -> float:
        return self.counts_per_m
