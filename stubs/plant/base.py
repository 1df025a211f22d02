"""The plant protocol every emulator drives, and a kinematic stand-in without physics.

A plant is the robot and its world: it accepts joint position, velocity, impedance and gripper
commands, advances in fixed steps, and reports measured state plus ground truth for an
evaluator. Emulators (UR RTDE, Dynamixel, CiA 402) own one plant each and step it in real time
with :class:`stubs.plant.realtime.RealtimeStepper`; the lockstep simulated cell steps it from a
virtual clock. ``KinematicPlant`` tracks commands with a first-order lag and rate limits: good
enough for protocol tests, no contact, no force.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import msgspec
import numpy as np


class PlantState(msgspec.Struct, frozen=True, kw_only=True):
    t_ns: int
    q: tuple[float, ...]
    qd: tuple[float, ...]
    effort: tuple[float, ...]
    wrench: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    """Wrist force-torque reading (Fx, Fy, Fz, Tx, Ty, Tz) in the sensor frame."""
    gripper: float = 0.0
    """Gripper opening in metres."""


class GroundTruth(msgspec.Struct, frozen=True, kw_only=True):
    """What only the simulator knows; the evaluator uses it, the runtime never does."""

    t_ns: int
    peg_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    hole_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    insertion_depth: float = 0.0
    peg_grasped: bool = False


@runtime_checkable
class Plant(Protocol):
    dof: int
    timestep_ns: int

    def reset(self, q: Sequence[float] | None = None) -> None: ...

    def command_position(self, q: Sequence[float]) -> None: ...

    def command_velocity(self, qd: Sequence[float]) -> None: ...

    def command_impedance(
        self, q: Sequence[float], stiffness: Sequence[float], damping: Sequence[float]
    ) -> None: ...

    def command_gripper(self, opening: float) -> None: ...

    def hold(self) -> None: ...

    def step(self, n: int = 1) -> None: ...

    def state(self) -> PlantState: ...

    def ground_truth(self) -> GroundTruth: ...


UR5E_HOME = (0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0)


class KinematicPlant:
    """Joints that follow their target with a first-order lag, inside velocity limits."""

    def __init__(
        self, dof: int = 6, timestep_ns: int = 2_000_000, time_constant_s: float = 0.02,
        v_max: float = 3.14, q0: Sequence[float] | None = None,
    ) -> None:
        self.dof = dof
        self.timestep_ns = timestep_ns
        self._tau = time_constant_s
        self._v_max = v_max
        self._t_ns = 0
        self.reset(q0)

    def reset(self, q: Sequence[float] | None = None) -> None:
        start = q if q is not None else (UR5E_HOME[: self.dof] + (0.0,) * self.dof)[: self.dof]
        self._q = np.array(start, dtype=float)
        self._qd = np.zeros(self.dof)
        self._target = self._q.copy()
        self._velocity_mode = False
        self._gripper = 0.04

    def command_position(self, q: Sequence[float]) -> None:
        self._target = np.array(q, dtype=float)
        self._velocity_mode = False

    def command_velocity(self, qd: Sequence[float]) -> None:
        self._qd_target = np.clip(np.array(qd, dtype=float), -self._v_max, self._v_max)
        self._velocity_mode = True

    def command_impedance(
        self, q: Sequence[float], stiffness: Sequence[float], damping: Sequence[float]
    ) -> None:
        self.command_position(q)

    def command_gripper(self, opening: float) -> None:
        self._gripper = float(opening)

    def hold(self) -> None:
        self.command_position(self._q)

    def step(self, n: int = 1) -> None:
        dt = self.timestep_ns * 1e-9
        for _ in range(n):
            if self._velocity_mode:
                qd = self._qd_target
            else:
                qd = np.clip((self._target - self._q) / max(self._tau, dt), -self._v_max,
                             self._v_max)
            self._q = self._q + qd * dt
            self._qd = qd
            self._t_ns += self.timestep_ns

    def state(self) -> PlantState:
        return PlantState(
            t_ns=self._t_ns, q=tuple(self._q.tolist()), qd=tuple(self._qd.tolist()),
            effort=(0.0,) * self.dof, gripper=self._gripper,
        )

    def ground_truth(self) -> GroundTruth:
        return GroundTruth(t_ns=self._t_ns)
