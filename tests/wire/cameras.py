"""Cameras for the link and hub tests: real :class:`~drivers.camera.CameraSource`s that draw a
pattern (a new one each frame, so a frame is never a copy of the last), on the test's clock."""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np

from drivers.camera import CameraFrame, CameraLost, make_frame
from kernel.manifest_cameras import CameraKind, CameraSettings
from kernel.wire import ImageEncoding

WIDTH, HEIGHT = 64, 48


class PatternCamera:
    """Draws frame ``k`` as a gradient shifted by ``k``; taken ``age_ns`` before ``clock()``.
    ``frames``: how many it gives before it is lost (None: forever); ``still``: the same
    picture every time (a frozen sensor)."""

    def __init__(self, name: str, clock: Callable[[], int], age_ns: int = 0,
                 frames: int | None = None, still: bool = False) -> None:
        self.name = name
        self.clock, self.age_ns, self.frames, self.still = clock, age_ns, frames, still
        self.count = 0
        self.opened = 0
        self._lock = threading.Lock()

    def open(self) -> None:
        self.opened += 1

    def read(self) -> CameraFrame:
        with self._lock:
            if self.frames is not None and self.count >= self.frames:
                raise CameraLost(f"{self.name}: the pattern ran out")
            self.count += 1
            k = (0 if self.still else self.count) + sum(self.name.encode())  # its own picture
        image = ((np.arange(WIDTH)[None, :, None] + np.arange(HEIGHT)[:, None, None] * 3
                  + np.arange(3)[None, None, :] * 50 + k) % 256).astype(np.uint8)
        return make_frame(self.name, image, self.clock() - self.age_ns, "cal-12")

    def close(self) -> None:
        """Nothing to release."""


def settings(name: str, encoding: ImageEncoding = ImageEncoding.RAW, rate_hz: float = 50.0,
             **changes: object) -> CameraSettings:
    return CameraSettings(name=name, source=CameraKind.OPENCV, device="pattern", width=WIDTH,
                          height=HEIGHT, rate_hz=rate_hz, calibration_epoch="cal-12",
                          encoding=encoding, **changes)  # type: ignore[arg-type]
