"""Encoder counts ↔ joint radians, per joint, and ↔ gripper opening in metres."""

from __future__ import annotations

import math
from dataclasses import dataclass

INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1


@dataclass(frozen=True, slots=True)
class JointScale:
    """How one drive's position counts map to its joint angle.

    ``q = direction * (counts - offset_counts) * 2π / counts_per_rev``, where ``counts_per_rev``
    counts one turn of the *joint* (encoder resolution times gear ratio) and ``offset_counts``
    is the reading at q = 0. ``gear_ratio`` only scales torque (motor side → joint side).
    """

    counts_per_rev: float
    direction: int = 1
    offset_counts: int = 0
    gear_ratio: float = 1.0

    @property
    def _rad_per_count(self) -> float:
        return 2.0 * math.pi / self.counts_per_rev

    def to_counts(self, q: float) -> int:
        """Nearest count for ``q`` radians; ``ValueError`` if it does not fit an INTEGER32."""
        counts = round(self.direction * q / self._rad_per_count) + self.offset_counts
        if not INT32_MIN <= counts <= INT32_MAX:
            raise ValueError(f"{q} rad is {counts} counts, outside the drive's INTEGER32 range")
        return counts

    def to_rad(self, counts: int) -> float:
        return self.direction * (counts - self.offset_counts) * self._rad_per_count

    def velocity_to_rad(self, counts_per_s: int) -> float:
        return self.direction * counts_per_s * self._rad_per_count

    def torque_to_nm(self, per_mille: int, rated_torque_mnm: int) -> float:
        """0x6077 (thousandths of rated motor torque) → joint torque in N·m."""
        return self.direction * per_mille * rated_torque_mnm * 1e-6 * self.gear_ratio


GRIPPER_STROKE_M = 0.085
"""Stroke of the cell's gripper (a 2F-85-class parallel gripper): commands are clipped to it."""
GRIPPER_COUNTS_PER_M = 1_000_000.0
"""One count per micrometre of opening (why: see ``CiA402Settings.gripper_counts_per_m``)."""


@dataclass(frozen=True, slots=True)
class GripperScale:
    """How the gripper drive's position counts map to the opening between the fingers.

    ``opening = counts / counts_per_m``: zero counts is fully closed, and the count grows as the
    fingers open (a gripper's own homing defines that zero, so there is no offset to configure).
    """

    counts_per_m: float

    def to_counts(self, opening_m: float) -> int:
        counts = round(opening_m * self.counts_per_m)
        if not INT32_MIN <= counts <= INT32_MAX:
            raise ValueError(f"{opening_m} m is {counts} counts, outside the drive's INTEGER32 "
                             "range")
        return counts

    def to_m(self, counts: int) -> float:
        return counts / self.counts_per_m
