"""The simulated cell's cameras: a wrist camera on the gripper and a scene camera over the table,
rendered offscreen (EGL, no display) from the plant's joints.

Rendering a 224 × 224 frame costs about 1 ms here without shadows and reflections (20 ms with),
and MuJoCo's renderer holds the GIL while it draws: on a thread of warden's process it stalled
the 2 ms control loop by up to 8 ms. So the pixels are drawn by a child process
(:mod:`stubs.plant.render_worker`, started with ``MUJOCO_GL=egl``), as a real camera is a device
of its own. :class:`RenderedCameras` owns one thread that, at the rate asked for, copies the
plant's joint positions (``qpos``: the caller's function, which takes the plant's lock if it has
one), stamps the capture time, hands them to the child and waits for its pixels (pipe I/O,
without the GIL); each :class:`RenderedCamera` hands out its newest frame as a
:class:`~drivers.camera.CameraSource`. The cameras are added to a copy of the cell's model
(``stubs/robot_model/cell.xml``) for rendering only: the plant's own model, and so its dynamics,
are untouched.
"""

from __future__ import annotations

import contextlib
import os
import select
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

import stubs.robot_model as rm
from drivers.camera import CameraFrame, CameraLost, make_frame
from stubs.child import PARENT_PID
from stubs.process import children_at_ordinary_priority


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
SIM_SPECS = {spec.name: spec for spec in (WRIST, SCENE)}
START_TIMEOUT_S = 15.0
"""A render child's start (MuJoCo's import, the model's compile, the GL context): about half a
second here, idle; longer than a run waits for a camera's first frame, so that wait decides."""
RENDER_TIMEOUT_S = 5.0
"""A frame the child has not drawn by then never comes: the child is killed."""


def render_model(specs: tuple[CameraSpec, ...]) -> mujoco.MjModel:
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
        self._frames: dict[str, CameraFrame] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self._worker: RenderWorker | None = None
        self._running = threading.Lock()
        self.failure: str | None = None
        """Why the renderer thread ended early (a GL context that would not open)."""

    def start(self) -> None:
        """Start rendering (again, after a stop: a camera that was lost is opened anew)."""
        with self._running:
            if self._thread is None:
                self._stop.clear()
                self.failure = None
                self._thread = threading.Thread(target=self._run, name="cameras", daemon=True)
                self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop rendering; a render child that does not answer in time is killed."""
        with self._running:
            thread, self._thread = self._thread, None
            if thread is None:
                return
            self._stop.set()
            self._wake.set()
            thread.join(timeout=timeout_s)
            worker = self._worker
            if thread.is_alive() and worker is not None:
                worker.kill()  # the thread is stuck in a read of a hung child: this ends it
                thread.join(timeout=timeout_s)

    def latest(self, name: str) -> CameraFrame | None:
        with self._lock:
            return self._frames.get(name)

    def trigger(self) -> None:
        """Render now, not at the next period: an observation is about to be taken."""
        self._wake.set()

    def camera(self, name: str) -> RenderedCamera:
        if name not in {spec.name for spec in self.specs}:
            raise ValueError(f"no rendered camera {name!r}")
        return RenderedCamera(name, self)

    def _run(self) -> None:
        try:
            self._worker = worker = RenderWorker(self.specs)
        except RenderFailed as error:  # no GL context there: say so, give no frames
            self.failure = str(error)
            return
        try:
            while not self._stop.is_set():
                started = time.monotonic()
                self._wake.clear()  # a trigger from here on renders again after this one
                self._render_all(worker)
                self._wake.wait(max(0.0, self.period_s - (time.monotonic() - started)))
        except RenderFailed as error:
            self.failure = str(error)
        finally:
            worker.close()

    def _render_all(self, worker: RenderWorker) -> None:
        t_capture = self._clock()
        pixels = worker.render(self._qpos())
        for spec, image in zip(self.specs, pixels, strict=True):
            frame = make_frame(spec.name, image, t_capture, self.calibration_epoch)
            with self._lock:
                self._frames[spec.name] = frame


class RenderFailed(Exception):
    """The render process did not start, or ended; the message says what it last said."""


class RenderWorker:
    """The child that draws (:mod:`stubs.plant.render_worker`) and its fixed-size exchange."""

    def __init__(self, specs: tuple[CameraSpec, ...]) -> None:
        self.specs = specs
        command = [sys.executable, "-m", "stubs.child", "stubs.plant.render_worker",
                   *(f"{s.name}:{s.width}x{s.height}" for s in specs)]
        with children_at_ordinary_priority():  # never at the control loop's SCHED_FIFO
            self._proc = subprocess.Popen(
                command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True,
                env={**os.environ, "MUJOCO_GL": "egl", PARENT_PID: str(os.getpid())})
        try:
            self.nq: int = struct.unpack("<I", self._read(4, START_TIMEOUT_S))[0]
        except RenderFailed:
            self.close()
            raise

    def render(self, qpos: np.ndarray) -> list[np.ndarray]:
        """Every camera's RGB image of the cell posed at ``qpos``."""
        stdin = self._proc.stdin
        if stdin is None or qpos.shape != (self.nq,):
            raise RenderFailed(f"the renderer takes {self.nq} joint positions, got "
                               f"{qpos.shape}")
        try:
            stdin.write(np.ascontiguousarray(qpos, dtype="<f8").tobytes())
            stdin.flush()
        except (BrokenPipeError, ValueError) as error:
            raise RenderFailed(f"the render process is gone ({error})") from None
        return [np.frombuffer(self._read(s.height * s.width * 3), dtype=np.uint8).reshape(
            s.height, s.width, 3) for s in self.specs]

    def kill(self) -> None:
        """End a child that stopped answering (its reader is then told so by the pipe)."""
        with contextlib.suppress(ProcessLookupError):
            self._proc.kill()

    def close(self) -> None:
        if self._proc.stdin is not None:
            with contextlib.suppress(OSError):
                self._proc.stdin.close()
        try:
            self._proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        if self._proc.stdout is not None:
            self._proc.stdout.close()

    def _read(self, size: int, timeout_s: float = RENDER_TIMEOUT_S) -> bytes:
        """``size`` bytes from the child within ``timeout_s`` (a hung child is a failure, and
        is killed, not waited for)."""
        stdout = self._proc.stdout
        if stdout is None:
            raise RenderFailed("the render process has no output")
        deadline = time.monotonic() + timeout_s
        chunks, got = [], 0
        while got < size:
            ready, _, _ = select.select([stdout], [], [], max(0.0, deadline - time.monotonic()))
            chunk = os.read(stdout.fileno(), size - got) if ready else None
            if not chunk:
                if chunk is None:
                    self.kill()
                why = "did not answer in time" if chunk is None else "ended"
                raise RenderFailed(f"the render process {why} (exit code {self._proc.poll()}; "
                                   "its own message is on stderr; offscreen rendering needs "
                                   "EGL)")
            chunks.append(chunk)
            got += len(chunk)
        return b"".join(chunks)


class RenderedCamera:
    """One rendered camera as a :class:`~drivers.camera.CameraSource`: its newest frame."""

    def __init__(self, name: str, cameras: RenderedCameras,
                 first_frame_timeout_s: float = START_TIMEOUT_S) -> None:
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

    def trigger(self) -> None:
        self._cameras.trigger()

    def read(self) -> CameraFrame:
        frame = self._cameras.latest(self.name)
        if frame is None:
            raise CameraLost(f"{self.name}: not open")
        return frame

    def close(self) -> None:
        self._cameras.stop()
