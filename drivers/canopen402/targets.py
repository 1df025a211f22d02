"""The joints' CSP targets: where a setpoint, a hold and the end of a quick stop put them.

An enabled CSP drive follows its target at once, so every target is a motion: a setpoint's is
clipped into the control loop's limits; a hold keeps the targets as they are (never a fresh
reading: a glitched one is a jump); only at activation and after a quick stop, whose ramp left
the drives short of or past their targets, are they set where the drives are, and then from a
plausible reading only (:mod:`drivers.plausible`: every joint reading the driver takes goes
through :attr:`Targets.readings`, the core's check), else the last plausible one.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

from drivers.base import ControlConfig
from drivers.canopen402._sdk import Node402, PdoVariable
from drivers.canopen402.process_data import joint_readings
from drivers.canopen402.tables import Index
from drivers.canopen402.units import JointScale
from drivers.plausible import LastPlausible


class Targets:
    def __init__(self, scales: Sequence[JointScale]) -> None:
        self._scales = tuple(scales)
        self._pdos: tuple[PdoVariable, ...] = ()
        self.readings = LastPlausible()
        """Every joint reading the driver takes, judged as the core judges its samples."""

    def bind(self, joints: Sequence[Node402]) -> None:
        """Write into these drives' RPDO target variables from now on."""
        self._pdos = tuple(node.rpdo[1][Index.TARGET_POSITION] for node in joints)

    def command(self, q: Sequence[float], control: ControlConfig) -> tuple[float, ...]:
        """Set a setpoint's targets, clipped into the limits; returns them in radians."""
        counts = [scale.to_counts(min(max(v, lo), hi)) for scale, v, lo, hi in zip(
            self._scales, q, control.q_lower, control.q_upper, strict=True)]
        for target, value in zip(self._pdos, counts, strict=True):
            target.raw = value
        return tuple(scale.to_rad(c) for scale, c in zip(self._scales, counts, strict=True))

    def kept(self) -> tuple[float, ...]:
        """The targets as they are, in radians."""
        return tuple(scale.to_rad(target.raw)
                     for scale, target in zip(self._scales, self._pdos, strict=True))

    def here(self, joints: Sequence[Node402], rated_torque: Sequence[int]) -> tuple[float, ...]:
        """Set every joint's target to its actual position, by a plausible reading (else the
        last plausible one: a glitched reading made the targets is a jump the drives follow);
        returns it in radians."""
        q, qd, _ = joint_readings(joints, self._scales, rated_torque)
        q = self.readings.believed(time.monotonic_ns(), q, qd) or q
        for scale, target, value in zip(self._scales, self._pdos, q, strict=True):
            target.raw = scale.to_counts(value)
        return q
