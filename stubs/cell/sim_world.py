"""The simulated cell in process: the MuJoCo plant behind the plant driver.

The world steps the physics one control period per tick (the plant runs in lockstep with the
control loop, whichever clock paces that loop) and tells what only a simulation can: the
ground truth the evaluator reads, and a parts feeder.

With ``[safety] sim_port`` set, the world also serves a test-only control port on loopback for
the independent safety monitor (``warden safety``): the plant's ground truth (joints, speeds,
wrist wrench) and a brake that holds the joints where they are and ignores every later joint
command (:mod:`stubs.plant.brake`). It runs on its own thread in warden's process; the plant
itself still moves only when warden's loop steps it.
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable
from typing import Any

import msgspec
import numpy as np

from drivers.base import Driver
from drivers.camera import CameraSource
from drivers.sim.driver import SimDriver
from kernel.manifest import Manifest, ManifestError
from kernel.manifest_cameras import CameraSettings
from stubs.fault_control import FaultControlServer
from stubs.plant.brake import BrakedPlant
from stubs.plant.cameras import SIM_SPECS, RenderedCameras
from stubs.plant.mujoco_plant import MujocoPlant
from stubs.plant.world_port import world_handlers
from stubs.reading_glitch import ReadingGlitch

CONTROL_HOST = "127.0.0.1"
"""Loopback only: the control port has no authentication, it is test tooling."""


def sim_world(manifest: Manifest) -> SimWorld:
    """The ``sim`` world for a manifest (the ``warden.worlds`` entry point)."""
    port = manifest.safety.sim_port if manifest.safety is not None else 0
    plant = MujocoPlant()
    period_ns = manifest.core.control_period_ns
    if period_ns % plant.timestep_ns:
        raise ManifestError(f"{manifest.path}: timing.control_period_ms: {period_ns / 1e6:g} ms "
                            "is not a whole number of the simulated plant's "
                            f"{plant.timestep_ns / 1e6:g} ms steps")
    try:
        return SimWorld(period_ns, plant=plant, control_port=port)
    except OSError as error:
        raise ManifestError(f"{manifest.path}: safety.sim_port: cannot serve the simulated "
                            f"world's control port on {CONTROL_HOST}:{port} ({error})") from None


class SimWorld:
    """The MuJoCo cell in-process, driven through :class:`drivers.sim.driver.SimDriver`."""

    has_ground_truth = True

    def __init__(self, period_ns: int, plant: MujocoPlant | None = None,
                 control_port: int = 0) -> None:
        self.plant = plant or MujocoPlant()
        if period_ns % self.plant.timestep_ns:
            raise ValueError(f"control period {period_ns} ns is not a multiple of the plant's "
                             f"{self.plant.timestep_ns} ns step")
        self._steps = period_ns // self.plant.timestep_ns
        self._lock = threading.Lock()
        self.brake = BrakedPlant(self.plant)
        self.glitch = ReadingGlitch()
        reported = _Reported(self.brake, self.glitch)
        self._driver = SimDriver(reported, lock=self._lock)  # type: ignore[arg-type]
        self.control: FaultControlServer | None = None
        if control_port:
            self.control = FaultControlServer(CONTROL_HOST, control_port,
                                              self._handlers()).start()

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

    def sim_camera(self, camera: CameraSettings, clock: Callable[[], int]) -> CameraSource:
        """One of the cell's cameras, drawn from this plant's joints by a render process
        (stubs/plant/cameras.py), its frames stamped by ``clock`` (the run's)."""
        spec = dataclasses.replace(SIM_SPECS[camera.name], width=camera.width,
                                   height=camera.height)

        def qpos() -> np.ndarray:
            with self._lock:
                return self.plant.data.qpos.copy()

        rendered = RenderedCameras((spec,), camera.rate_hz, qpos, camera.calibration_epoch,
                                   clock)
        return rendered.camera(camera.name)

    def inject(self, fault: str, **fields: Any) -> dict[str, Any]:
        """What the control port answers, in process (a lockstep run's hooks)."""
        return {"ok": True, **(self._handlers()[fault]({"fault": fault, **fields}) or {})}

    def close(self) -> None:
        """Stop the control port; the plant lives and dies with the process."""
        if self.control is not None:
            self.control.stop()
            self.control = None

    def _handlers(self) -> dict[str, Any]:
        def brake(_: dict[str, Any]) -> dict[str, Any]:
            with self._lock:
                self.brake.engage()
            return {"engaged": True}

        def brake_state(_: dict[str, Any]) -> dict[str, Any]:
            with self._lock:
                return {"engaged": self.brake.engaged, "ignored": self.brake.ignored}

        return {**world_handlers(self.plant, self._lock), "brake": brake,
                "brake_state": brake_state, "reading_glitch": self.glitch.start}


class _Reported:
    """The plant as its sensors report it: an injected reading glitch shows in ``state()``
    (what the driver reads), never in what the plant does or what the ground truth says."""

    def __init__(self, plant: BrakedPlant, glitch: ReadingGlitch) -> None:
        self._plant, self._glitch = plant, glitch

    def state(self) -> Any:
        state = self._plant.state()
        return msgspec.structs.replace(state, q=self._glitch.apply(state.q))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._plant, name)
