"""What the cell runs against, and what only the simulation can tell (ground truth).

A ``World`` owns the physical side the driver talks to. For the in-process plant it also steps
the physics, one control period per tick (the plant runs in lockstep with the control loop,
whichever clock paces that loop). For an emulated device the emulator steps its own plant and
the world only starts and stops it.
"""

from __future__ import annotations

import threading
from typing import Protocol

from drivers.base import Driver
from drivers.sim.driver import SimDriver
from stubs.plant.mujoco_plant import MujocoPlant


class World(Protocol):
    def driver(self) -> Driver: ...

    def advance(self) -> None:
        """One control period of physics has passed (no-op where the device steps itself)."""
        ...

    def insertion_depth(self) -> float:
        """Ground truth for the independent evaluator, metres."""
        ...

    def feed_peg(self) -> None:
        """The feeder presents a new peg for the next cycle."""
        ...

    def close(self) -> None: ...


class SimWorld:
    """The MuJoCo cell in-process, driven through :class:`drivers.sim.driver.SimDriver`."""

    def __init__(self, period_ns: int, plant: MujocoPlant | None = None) -> None:
        self.plant = plant or MujocoPlant()
        if period_ns % self.plant.timestep_ns:
            raise ValueError(f"control period {period_ns} ns is not a multiple of the plant's "
                             f"{self.plant.timestep_ns} ns step")
        self._steps = period_ns // self.plant.timestep_ns
        self._lock = threading.Lock()
        self._driver = SimDriver(self.plant, lock=self._lock)

    def driver(self) -> Driver:
        return self._driver

    def advance(self) -> None:
        with self._lock:
            self.plant.step(self._steps)

    def insertion_depth(self) -> float:
        with self._lock:
            return self.plant.ground_truth().insertion_depth

    def feed_peg(self) -> None:
        with self._lock:
            self.plant.respawn_peg()

    def close(self) -> None:
        """Nothing to release: the plant lives and dies with the process."""
