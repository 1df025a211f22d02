"""The simulated cell's cameras: a wrist camera on the gripper and a scene camera over the
table, rendered offscreen (EGL, no display) in the plant's process.

Rendering a 224 × 224 frame costs about 6 ms here: never on the control loop's thread.
:class:`RenderedCameras` owns one thread (and its GL context, which is bound to it) that, at
the rate asked for, copies the plant's joint positions (``qpos``: the caller's function, which
takes the plant's lock if it has one), poses a private copy of the cell's model with them and
renders every camera; each :class:`RenderedCamera` hands out its newest frame as a
:class:`~drivers.camera.CameraSource`. The cameras are added to a copy of the cell's model
(``stubs/robot_model/cell.xml``) for rendering only: the plant's own model, and so its
dynamics, are untouched.

Offscreen rendering needs ``MUJOCO_GL=egl`` in the environment before MuJoCo is first imported
(MuJoCo picks its GL platform then; the tests' conftest sets it).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

import stubs.robot_model as rm
from drivers.camera import CameraFrame, CameraLost, make_frame


@dataclass(frozen=True, slots=True)
class CameraSpec:
    name: str
    body: str
    """The body it is fixed to ("" for the world)."""
    pos: tuple[float, float, float]
    xyaxes: tuple[float, float, float, float, float, float]
    width: int = 224
    height: int = 224
    fovy: float = 60.0


WRIST = CameraSpec("wrist_rgb", "gripper", (0.0, 0.07, 0.02), (1.0, 0.0, 0.0, 0.0, -1.0, 0.0))
"""Beside the fingers, looking along the tool's approach axis."""
SCENE = CameraSpec("scene_rgb", "", (0.35, -0.85, 0.75), (0.92, 0.39, 0.0, -0.2, 0.47, 0.86))
"""In front of the table, looking down at the arm, the peg and the fixture."""


def _render_model(specs: tuple[CameraSpec, ...]) -> mujoco.MjModel:
    spec = mujoco.MjSpec.from_string(rm.CELL_MODEL.read_text(encoding="utf-8"),
                                     include={rm.CELL_ARM_INCLUDE: rm.ARM_MODEL.read_bytes()})
    for camera in specs:
        body = spec.worldbody if not camera.body else spec.body(camera.body)
        if body is None:
            raise ValueError(f"camera {camera.name}: the cell has no body {camera.body!r}")
        body.add_camera(name=camera.name, pos=list(camera.pos), xyaxes=list(camera.xyaxes),
                        fovy=camera.fovy)
    return spec.compile()


class RenderedCameras:
    """The renderer thread (module docstring)."""

    def __init__(self, specs: tuple[CameraSpec, ...], rate_hz: float,
                 qpos: Callable[[], np.ndarray], calibration_epoch: str,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        if not rate_hz > 0:
            raise ValueError("a camera rate must be positive")
        self.specs = specs
        self.period_s = 1.0 / rate_hz
        self.calibration_epoch = calibration_epoch
        self._qpos, self._clock = qpos, clock
        self._model = _render_model(specs)
        self._data = mujoco.MjData(self._model)
        self._frames: dict[str, CameraFrame] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.failure: str | None = None
        """Why the renderer thread ended early (a GL context that would not open)."""

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="cameras", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        thread, self._thread = self._thread, None
        if thread is not None:
            self._stop.set()
            thread.join(timeout=5.0)

    def latest(self, name: str) -> CameraFrame | None:
        with self._lock:
            return self._frames.get(name)

    def camera(self, name: str) -> RenderedCamera:
        if name not in {spec.name for spec in self.specs}:
            raise ValueError(f"no rendered camera {name!r}")
        return RenderedCamera(name, self)

    def _run(self) -> None:
        try:
            renderers = {s.name: mujoco.Renderer(self._model, s.height, s.width)
                         for s in self.specs}
        except Exception as error:  # no GL context here: say so, give no frames
            self.failure = (f"offscreen rendering failed (MUJOCO_GL={os.environ.get('MUJOCO_GL')}"
                            f", egl needs setting before MuJoCo is imported): {error}")
            return
        try:
            while not self._stop.is_set():
                started = time.monotonic()
                self._render_all(renderers)
                self._stop.wait(max(0.0, self.period_s - (time.monotonic() - started)))
        finally:
            for renderer in renderers.values():
                renderer.close()

    def _render_all(self, renderers: dict[str, mujoco.Renderer]) -> None:
        t_capture = self._clock()
        self._data.qpos[:] = self._qpos()
        mujoco.mj_kinematics(self._model, self._data)
        mujoco.mj_camlight(self._model, self._data)
        for name, renderer in renderers.items():
            renderer.update_scene(self._data, camera=name)
            frame = make_frame(name, renderer.render(), t_capture, self.calibration_epoch)
            with self._lock:
                self._frames[name] = frame


class RenderedCamera:
    """One rendered camera as a :class:`~drivers.camera.CameraSource`: its newest frame."""

    def __init__(self, name: str, cameras: RenderedCameras,
                 first_frame_timeout_s: float = 5.0) -> None:
        self.name = name
        self._cameras = cameras
        self._timeout_s = first_frame_timeout_s

    def open(self) -> None:
        """Raises:
            CameraLost: no frame within the first frame's timeout (no GL context, say).
        """
        self._cameras.start()
        deadline = time.monotonic() + self._timeout_s
        while self._cameras.latest(self.name) is None:
            if self._cameras.failure is not None or time.monotonic() > deadline:
                raise CameraLost(f"{self.name}: {self._cameras.failure or 'no frame rendered'}")
            time.sleep(0.005)

    def read(self) -> CameraFrame:
        frame = self._cameras.latest(self.name)
        if frame is None:
            raise CameraLost(f"{self.name}: not open")
        return frame

    def close(self) -> None:
        self._cameras.stop()
