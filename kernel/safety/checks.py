"""What the monitor checks on every sample: plain comparisons, written for the monitor alone.

The limits are the manifest's numbers (the ``[robot]`` limits warden enforces, read by the
monitor's own view with the same parser warden's configuration uses, plus the ``[safety]``
margins and force limit); nothing here runs warden's
gates, projection or motion code, so a mistake there is not a mistake here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

from kernel.manifest_tables import RobotLimits
from kernel.safety.settings import SafetySettings


class Breach(StrEnum):
    """Why the monitor stops the arm."""

    POSITION = "position"
    """A joint is outside its position limit (plus ``position_margin_rad``)."""
    VELOCITY = "velocity"
    """A joint is faster than its velocity limit (plus ``velocity_margin``)."""
    FORCE = "force"
    """The wrist force is above ``max_wrist_force_n``."""
    HEARTBEAT_LOST = "heartbeat_lost"
    """warden's heartbeat stopped without an END."""
    MOTION_WITHOUT_WARDEN = "motion_without_warden"
    """The arm moves while no warden run is heartbeating (none started, or one ended)."""
    DEVICE_LOST = "device_lost"
    """The monitor's own view of the device went stale or stopped answering."""
    SPACE = "space"
    """The measured arm is inside a keep-out zone, or closer to an obstacle than any phase's
    clearance (``[geometry]``; kernel/safety/space.py)."""


@dataclass(frozen=True, slots=True)
class Sample:
    """One reading of the device through the monitor's own connection."""

    q: tuple[float, ...]
    qd: tuple[float, ...]
    force_n: float | None
    """Norm of the wrist force (N); None where the monitor cannot read a wrist sensor."""

    @property
    def fastest(self) -> float:
        return max((abs(v) for v in self.qd), default=0.0)


@dataclass(frozen=True, slots=True)
class Finding:
    breach: Breach
    detail: str

    def __str__(self) -> str:
        return f"{self.breach}: {self.detail}"


@dataclass(frozen=True, slots=True)
class Limits:
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    velocity: tuple[float, ...]
    max_force_n: float | None
    position_margin: float
    velocity_margin: float

    @classmethod
    def of(cls, robot: RobotLimits, safety: SafetySettings) -> Limits:
        """The arm joints' limits (the gripper's dimension, if any, is not an arm joint)."""
        arm = robot.arm
        return cls(tuple(robot.lower[i] for i in arm), tuple(robot.upper[i] for i in arm),
                   tuple(robot.velocity[i] for i in arm), safety.max_wrist_force_n,
                   safety.position_margin_rad, safety.velocity_margin)


def breaches(sample: Sample, limits: Limits) -> list[Finding]:
    """Every limit the sample breaks, in joint order; a value that is not finite breaks it."""
    found: list[Finding] = []
    if len(sample.q) != len(limits.lower) or len(sample.qd) != len(limits.velocity):
        return [Finding(Breach.DEVICE_LOST, f"the device reports {len(sample.q)} positions and "
                        f"{len(sample.qd)} velocities, the manifest has {len(limits.lower)} "
                        f"joints")]
    found += _positions(sample.q, limits)
    found += _velocities(sample.qd, limits)
    if limits.max_force_n is not None and sample.force_n is not None and not (
            sample.force_n <= limits.max_force_n):
        found.append(Finding(Breach.FORCE, f"wrist force {sample.force_n:.1f} N > "
                             f"{limits.max_force_n:g} N"))
    return found


def _positions(q: Sequence[float], limits: Limits) -> list[Finding]:
    margin = limits.position_margin
    return [Finding(Breach.POSITION, f"joint {j} at {v:.4f} rad, limits [{lo:g}, {hi:g}]")
            for j, (v, lo, hi) in enumerate(zip(q, limits.lower, limits.upper, strict=True))
            if not (lo - margin <= v <= hi + margin)]


def _velocities(qd: Sequence[float], limits: Limits) -> list[Finding]:
    scale = 1.0 + limits.velocity_margin
    return [Finding(Breach.VELOCITY, f"joint {j} at {v:.3f} rad/s, limit {vmax:g} rad/s")
            for j, (v, vmax) in enumerate(zip(qd, limits.velocity, strict=True))
            if not (math.isfinite(v) and abs(v) <= vmax * scale)]
