"""The simulated cell in process: the MuJoCo plant behind the plant driver.

The world steps the physics one control period per tick (the plant runs in lockstep with the
control loop, whichever clock paces that loop) and tells what only a simulation can: the
ground truth the evaluator reads, and a parts feeder.
"""

from __future__ import annotations

import threading

from drivers.base import Driver
from drivers.sim.driver import SimDriver
from kernel.manifest import Manifest, ManifestError
from stubs.plant.mujoco_plant import MujocoPlant


def sim_world(manifest: Manifest) -> SimWorld:
    """The ``sim`` world for a manifest (the ``warden.worlds`` entry point)."""
    if manifest.driver_settings:
        key = next(iter(manifest.driver_settings))
        raise ManifestError(f"{manifest.path}: driver.{key}: unknown key (the sim driver "
                            "takes no settings)")
    return SimWorld(manifest.core.control_period_ns)


class SimWorld:
    """The MuJoCo cell in-process, driven through :class:`drivers.sim.driver.SimDriver`."""

    has_ground_truth = True

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

    def feed_part(self) -> None:
        with self._lock:
            self.plant.respawn_peg()

    def close(self) -> None:
        """Nothing to release: the plant lives and dies with the process."""
