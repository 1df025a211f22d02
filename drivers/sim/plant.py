"""What the plant driver needs of a plant: the commands it sends and the state it reads.

Defined here, by the driver, so the driver depends on no plant implementation; the plants in
``stubs/plant`` (MuJoCo, kinematic) satisfy it structurally. Stepping the plant is not part of
it: whoever owns time does that (the lockstep cell, or a real-time stepper).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable


@runtime_checkable
class PlantReading(Protocol):
    """One measured state of the plant, in SI units."""

    @property
    def q(self) -> tuple[float, ...]: ...

    @property
    def qd(self) -> tuple[float, ...]: ...

    @property
    def effort(self) -> tuple[float, ...]: ...

    @property
    def wrench(self) -> tuple[float, ...]:
        """Wrist force-torque (Fx, Fy, Fz, Tx, Ty, Tz) in the sensor frame."""
        ...

    @property
    def gripper(self) -> float:
        """Gripper opening in metres."""
        ...


@runtime_checkable
class SimulatedPlant(Protocol):
    @property
    def dof(self) -> int: ...

    def command_position(self, q: Sequence[float]) -> None: ...

    def command_velocity(self, qd: Sequence[float]) -> None: ...

    def command_impedance(
        self, q: Sequence[float], stiffness: Sequence[float], damping: Sequence[float]
    ) -> None: ...

    def command_gripper(self, opening: float) -> None: ...

    def hold(self) -> None:
        """Bring the joints to rest where they are."""
        ...

    def state(self) -> PlantReading: ...
