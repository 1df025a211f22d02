"""``warden check``'s camera rows: each ``[[cameras]]`` entry opened as a run would open it and
read for a moment, on a thread of its own (an OpenCV read blocks until a frame is there).

An OpenCV camera is READY when it opens at the manifest's size and gives frames; the row says
how many in how long, and whether they changed (a device that repeats one frame is frozen). A
simulated camera renders the run's plant, which check does not run: NOT EXERCISED. How a run
carries frames: docs/architecture.md, "Cameras".
"""

from __future__ import annotations

import asyncio
import time

from drivers.camera import CameraFrame, CameraLost
from drivers.opencv_camera import OpenCvCamera
from drivers.readiness import Finding, judged, not_exercised
from kernel.manifest import Manifest
from kernel.manifest_cameras import CameraKind, CameraSettings

READ_S = 1.0
"""How long each camera is read."""
MOST_FRAMES = 120


async def camera_rows(manifest: Manifest) -> list[Finding]:
    return [await asyncio.to_thread(_row, camera) for camera in manifest.cameras]


def _row(camera: CameraSettings) -> Finding:
    name = f"camera {camera.name}"
    expected = f"{camera.width}x{camera.height} frames"
    if camera.source is CameraKind.SIM:
        return not_exercised(name, expected, "rendered from the run's plant, which check does "
                             "not run")
    source = OpenCvCamera(camera.name, camera.opencv_device, camera.width, camera.height,
                          camera.calibration_epoch)
    frames: list[CameraFrame] = []
    started = time.monotonic()
    try:
        source.open()
        while time.monotonic() - started < READ_S and len(frames) < MOST_FRAMES:
            frames.append(source.read())
    except CameraLost as error:
        if not frames:
            return judged(name, expected, "no frame", [str(error)])
    finally:
        source.close()
    took = time.monotonic() - started
    distinct = len({frame.digest for frame in frames})
    measured = (f"{len(frames)} frames in {took:.2f} s, {distinct} different, from "
                f"{camera.device}")
    problems = [f"{len(frames)} identical frames: a frozen camera"] if (
        len(frames) > 2 and distinct == 1) else []
    return judged(name, expected, measured, problems)
