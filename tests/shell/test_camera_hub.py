"""The camera hub (kernel/shell/cameras.py): each camera read on its own thread, judged lost
when its newest frame is too old, frozen when it repeats itself, back when it sees again; and
an observation withheld while any camera has no fresh frame. The OpenCV path is exercised with
a recorded video that ends (a camera unplugged) and is opened again (plugged back in)."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from drivers.camera import make_frame
from drivers.opencv_camera import OpenCvCamera
from kernel.core.events import CameraStatus
from kernel.shell.cameras import CameraHealth, CameraHub, CameraUnavailable
from tests.wire.cameras import HEIGHT, WIDTH, PatternCamera, settings

MS = 1_000_000


def _frame(k: int, t_ms: int) -> object:
    image = np.full((HEIGHT, WIDTH, 3), k % 256, dtype=np.uint8)
    return make_frame("wrist_rgb", image, t_ms * MS, "cal-12")


def test_health_reports_each_change_once() -> None:
    health = CameraHealth(settings("wrist_rgb", rate_hz=50.0, freeze_frames=3))  # age 60 ms
    assert health.judge(None, "not opened yet", 0).status is CameraStatus.LOST
    assert health.judge(None, "not opened yet", 5 * MS) is None  # still lost: said once
    first = _frame(1, 10)
    back = health.judge(first, None, 20 * MS)
    assert back is not None and back.status is CameraStatus.BACK
    assert health.judge(first, None, 69 * MS) is None  # 59 ms old: fresh enough
    lost = health.judge(first, None, 71 * MS)
    assert lost is not None and lost.status is CameraStatus.LOST and "61 ms old" in lost.detail
    assert health.judge(_frame(2, 80), None, 81 * MS).status is CameraStatus.BACK
    assert health.judge(_frame(2, 90), None, 91 * MS) is None  # twice the same: not yet
    frozen = health.judge(_frame(2, 100), None, 101 * MS)
    assert frozen is not None and frozen.status is CameraStatus.FROZEN
    assert health.judge(_frame(2, 100), None, 200 * MS) is None  # frozen, then stale: down
    assert health.judge(_frame(3, 210), None, 211 * MS).status is CameraStatus.BACK


def _clock() -> int:
    return time.monotonic_ns()


def test_an_observation_is_withheld_while_a_camera_has_no_fresh_frame() -> None:
    wrist = PatternCamera("wrist_rgb", _clock)
    scene = PatternCamera("scene_rgb", _clock, frames=10)  # 10 frames at 50 Hz, then lost
    hub = CameraHub((settings("wrist_rgb"), settings("scene_rgb")),
                    {"wrist_rgb": wrist, "scene_rgb": scene})
    hub.start()
    try:
        hub.wait_first_frames(5.0)
        assert hub.check(_clock()) == []  # up from the start: nothing to report
        images = hub.images(_clock())
        assert images is not None and [i.frame.camera for i in images] == ["wrist_rgb",
                                                                            "scene_rgb"]
        deadline = time.monotonic() + 5.0
        events = []
        while not events and time.monotonic() < deadline:
            events = hub.check(_clock())
            time.sleep(0.01)
        assert [(e.camera, e.status) for e in events] == [("scene_rgb", CameraStatus.LOST)]
        assert "ran out" in events[0].detail  # why the reader has no newer frame
        assert hub.images(_clock()) is None and hub.withheld >= 1
        assert scene.opened >= 1
    finally:
        hub.stop()


def test_a_camera_that_never_gives_a_frame_fails_the_start() -> None:
    dead = PatternCamera("wrist_rgb", _clock, frames=0)
    hub = CameraHub((settings("wrist_rgb"),), {"wrist_rgb": dead})
    hub.start()
    try:
        with pytest.raises(CameraUnavailable, match=r"camera wrist_rgb: no frame in 0\.3 s"):
            hub.wait_first_frames(0.3)
    finally:
        hub.stop()


def _video(path: Path, frames: int) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (WIDTH, HEIGHT))
    for k in range(frames):
        writer.write(np.full((HEIGHT, WIDTH, 3), (k * 40) % 256, dtype=np.uint8))
    writer.release()
    return path


def test_a_video_that_ends_is_a_lost_camera_and_its_reopening_brings_it_back(
        tmp_path: Path) -> None:
    video = _video(tmp_path / "wrist.avi", 5)
    camera = OpenCvCamera("wrist_rgb", str(video), WIDTH, HEIGHT, "cal-12", _clock)
    hub = CameraHub((settings("wrist_rgb", rate_hz=50.0),), {"wrist_rgb": camera})
    hub.start()
    seen: list[CameraStatus] = []
    try:
        deadline = time.monotonic() + 8.0
        while seen[-2:] != [CameraStatus.LOST, CameraStatus.BACK] and time.monotonic() < deadline:
            seen += [e.status for e in hub.check(_clock())]
            time.sleep(0.005)
    finally:
        hub.stop()
    # No frame yet (LOST), the file plays (BACK), ends (LOST), is opened again and plays.
    assert seen[-2:] == [CameraStatus.LOST, CameraStatus.BACK], seen


class _PolicyRecording(PatternCamera):
    """Remembers the scheduling policy of the thread that reads it."""

    policies: set[int]

    def read(self):  # type: ignore[no-untyped-def]
        self.policies.add(os.sched_getscheduler(0))
        return super().read()


def test_a_camera_is_read_at_the_ordinary_policy_even_when_the_loop_is_real_time() -> None:
    camera = _PolicyRecording("wrist_rgb", _clock)
    camera.policies = set()
    hub = CameraHub((settings("wrist_rgb"),), {"wrist_rgb": camera})
    started: dict[str, int] = {}

    def real_time_loop() -> None:  # what the control loop's thread is when it starts the hub
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
        except PermissionError:
            return
        started["policy"] = os.sched_getscheduler(0)
        hub.start()

    thread = threading.Thread(target=real_time_loop)
    thread.start()
    thread.join()
    if not started:
        hub.stop()
        pytest.skip("not exercised: this user may not set SCHED_FIFO")
    try:
        hub.wait_first_frames(5.0)
    finally:
        hub.stop()
    assert started["policy"] == os.SCHED_FIFO and camera.policies == {os.SCHED_OTHER}


def test_a_reader_stuck_in_a_read_does_not_hold_the_stop_past_its_deadline() -> None:
    release = threading.Event()
    blocked = threading.Semaphore(0)

    class Unplugged(PatternCamera):
        def read(self):  # type: ignore[no-untyped-def]
            if self.count >= 1:
                blocked.release()
                release.wait(10.0)  # a V4L2 read on a device that went away
            return super().read()

    names = ("wrist_rgb", "scene_rgb")
    hub = CameraHub(tuple(settings(n) for n in names), {n: Unplugged(n, _clock) for n in names})
    hub.start()
    hub.wait_first_frames(5.0)
    for _ in names:
        assert blocked.acquire(timeout=5.0)  # both readers are in the read that hangs
    try:
        # One deadline for all: each join gets what is left of it, so this returns, with
        # both named, although neither read ever returns on its own.
        assert hub.stop(timeout_s=0.3) == list(names)
    finally:
        release.set()
