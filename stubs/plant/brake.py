"""A brake on a plant: once engaged, the joints hold where they were and ignore commands.

What the safety monitor's stop path does to the simulated cell (through the world's control
port): the plant holds its position at that instant (MuJoCo's position servo decelerates it
there) and every later joint command is ignored, as a braked arm ignores its drives. The
gripper is not braked: a held part stays held, as it would on a real arm whose program stops.
Engaged until the plant is thrown away (a new run): a safety stop is not undone from inside.
"""

from __future__ import annotations

from collections.abc import Sequence

from stubs.plant.base import PlantState


class BrakedPlant:
    """Wraps a plant (MuJoCo or kinematic); everything but joint commands passes through."""

    def __init__(self, plant: object) -> None:
        self._plant = plant
        self.engaged = False
        self.ignored = 0
        """Joint commands ignored since the brake engaged."""

    def engage(self) -> None:
        if not self.engaged:
            self.engaged = True
            self._plant.hold()  # type: ignore[attr-defined]

    def command_position(self, q: Sequence[float]) -> None:
        if self._braked():
            return
        self._plant.command_position(q)  # type: ignore[attr-defined]

    def command_velocity(self, qd: Sequence[float]) -> None:
        if self._braked():
            return
        self._plant.command_velocity(qd)  # type: ignore[attr-defined]

    def command_impedance(self, q: Sequence[float], stiffness: Sequence[float],
                          damping: Sequence[float]) -> None:
        if self._braked():
            return
        self._plant.command_impedance(q, stiffness, damping)  # type: ignore[attr-defined]

    def hold(self) -> None:
        if not self.engaged:  # engaged: it holds where the brake caught it, not where it is
            self._plant.hold()  # type: ignore[attr-defined]

    def state(self) -> PlantState:
        return self._plant.state()  # type: ignore[attr-defined,no-any-return]

    def __getattr__(self, name: str) -> object:
        # dof, timestep_ns, step, ground_truth, command_gripper, respawn_peg, ...
        return getattr(self._plant, name)

    def _braked(self) -> bool:
        if self.engaged:
            self.ignored += 1
        return self.engaged
