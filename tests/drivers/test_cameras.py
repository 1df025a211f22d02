"""Camera sources (drivers/camera.py): OpenCV reading a recorded video through the same calls
a V4L2 device takes, and the simulated cell's MuJoCo cameras rendered offscreen (EGL) on a
thread of their own."""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import mujoco
import numpy as np
import pytest

from drivers.camera import CameraLost, FreezeWatch, make_frame
from drivers.opencv_camera import OpenCvCamera
from stubs.plant.cameras import SCENE, WRIST, RenderedCameras, render_model

WIDTH, HEIGHT = 64, 48
COLOURS_BGR = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0), (0, 255, 255)]


class _Ticks:
    """A clock that counts, and remembers which threads read it."""

    def __init__(self) -> None:
        self.t = 0
        self.threads: set[int] = set()

    def __call__(self) -> int:
        self.threads.add(threading.get_ident())
        self.t += 1_000_000
        return self.t


def _video(path: Path, colours: list[tuple[int, int, int]]) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (WIDTH, HEIGHT))
    assert writer.isOpened()
    for colour in colours:
        writer.write(np.full((HEIGHT, WIDTH, 3), colour, dtype=np.uint8))
    writer.release()
    return path


def test_a_recorded_video_is_read_frame_by_frame_in_rgb_on_the_robots_clock(
        tmp_path: Path) -> None:
    clock = _Ticks()
    camera = OpenCvCamera("wrist_rgb", str(_video(tmp_path / "wrist.avi", COLOURS_BGR)),
                          WIDTH, HEIGHT, "cal-12", clock)
    camera.open()
    frames = [camera.read() for _ in COLOURS_BGR]
    with pytest.raises(CameraLost, match="gave no frame"):  # the file ended: the camera is lost
        camera.read()
    camera.close()
    for frame, (b, g, r) in zip(frames, COLOURS_BGR, strict=True):
        assert frame.image.shape == (HEIGHT, WIDTH, 3) and frame.image.dtype == np.uint8
        mean = frame.image.reshape(-1, 3).mean(axis=0)  # RGB now; MJPG is lossy: near enough
        assert np.allclose(mean, (r, g, b), atol=12), (mean, (r, g, b))
        assert not frame.image.flags.writeable and frame.calibration_epoch == "cal-12"
    assert len({frame.digest for frame in frames}) == len(frames)
    times = [frame.t_capture_ns for frame in frames]
    assert times == sorted(times) and len(set(times)) == len(times)


def test_a_camera_that_does_not_open_or_gives_another_size_is_lost(tmp_path: Path) -> None:
    with pytest.raises(CameraLost, match="does not open"):
        OpenCvCamera("scene_rgb", str(tmp_path / "missing.avi"), WIDTH, HEIGHT, "c").open()
    video = str(_video(tmp_path / "small.avi", COLOURS_BGR[:2]))
    with pytest.raises(CameraLost, match="64x48 frames, the manifest says 224x224"):
        OpenCvCamera("scene_rgb", video, 224, 224, "c").open()
    with pytest.raises(CameraLost, match="not open"):
        OpenCvCamera("scene_rgb", video, WIDTH, HEIGHT, "c").read()


def test_a_frozen_camera_is_told_by_repeated_frames() -> None:
    watch = FreezeWatch(repeats=3)
    still = np.zeros((4, 4, 3), dtype=np.uint8)
    moving = np.ones((4, 4, 3), dtype=np.uint8)
    seen = [watch.frozen(make_frame("c", image, k, "e"))
            for k, image in enumerate([still, still, moving, still, still, still, moving])]
    assert seen == [False, False, False, False, False, True, False]
    with pytest.raises(CameraLost, match="not H x W x 3 uint8"):
        make_frame("c", np.zeros((4, 4), dtype=np.uint8), 0, "e")


def test_the_cells_cameras_render_on_their_own_thread_and_see_the_arm_move() -> None:
    small = tuple(dataclasses.replace(spec, width=64, height=64) for spec in (WRIST, SCENE))
    model = render_model(small)
    qpos = model.qpos0.copy()
    clock = _Ticks()
    cameras = RenderedCameras(small, rate_hz=200.0, qpos=lambda: qpos.copy(),
                              calibration_epoch="sim-1", clock=clock)
    wrist, scene = cameras.camera("wrist_rgb"), cameras.camera("scene_rgb")
    wrist.open()
    scene.open()
    try:
        before = scene.read()
        qpos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "shoulder_pan_joint")] += 0.8
        _wait_for(lambda: scene.read().t_capture_ns > before.t_capture_ns + 2_000_000)
        after, seen_by_wrist = scene.read(), wrist.read()
    finally:
        wrist.close()
    assert before.image.shape == (64, 64, 3) and seen_by_wrist.image.shape == (64, 64, 3)
    assert before.image.std() > 0 and seen_by_wrist.image.std() > 0  # not a blank picture
    assert after.digest != before.digest  # the arm turned in the scene camera's view
    assert threading.get_ident() not in clock.threads  # never rendered on the caller's thread
    assert cameras.failure is None


def _wait_for(condition: Callable[[], bool], timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


def test_a_rendered_camera_closed_after_a_loss_renders_again_when_opened() -> None:
    small = (dataclasses.replace(WRIST, width=32, height=32),)
    qpos = render_model(small).qpos0.copy()
    cameras = RenderedCameras(small, rate_hz=50.0, qpos=lambda: qpos.copy(),
                              calibration_epoch="sim-1")
    camera = cameras.camera("wrist_rgb")
    camera.open()
    first = camera.read()
    camera.close()  # what a camera reader does when it lost the camera
    camera.open()   # ... and when it opens it again
    try:
        _wait_for(lambda: camera.read().t_capture_ns > first.t_capture_ns)
    finally:
        camera.close()
    assert cameras.failure is None
