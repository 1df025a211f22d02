"""What the UR driver makes of a setpoint before it reaches ur_rtde: six finite numbers, clipped
to the control loop's limits (the library range-checks only its own arguments)."""

from __future__ import annotations

import math
import time

from assurance.reasons import ReasonCode
from drivers.base import Applied, CommandKind, ControlConfig
from drivers.ur_rtde import tables


def well_formed(values: tuple[float, ...]) -> bool:
    """Six finite numbers: anything else is refused before it reaches the library."""
    return len(values) == tables.DOF and all(math.isfinite(v) for v in values)


def clip_position(control: ControlConfig | None, q: tuple[float, ...]) -> tuple[float, ...]:
    if control is None:
        return tuple(q)
    low, high = control.q_lower, control.q_upper
    return tuple(min(max(v, lo), hi) for v, lo, hi in zip(q, low, high, strict=True))


def clip_velocity(control: ControlConfig | None, qd: tuple[float, ...]) -> tuple[float, ...]:
    limits = control.v_max if control else (tables.JOINT_VELOCITY_RANGE[1],) * tables.DOF
    return tuple(min(max(v, -m), m) for v, m in zip(qd, limits, strict=True))


def refused(kind: CommandKind, reason: ReasonCode) -> Applied:
    return Applied(kind=kind, t_mono_ns=time.monotonic_ns(), accepted=False, reason=reason)
