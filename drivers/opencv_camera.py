"""A camera through OpenCV (``opencv-python-headless``): a V4L2/USB device by index or path,
or a recorded video file read through the same calls (how the tests exercise it).

OpenCV's ``read`` blocks until a frame is there (a device at 30 Hz: up to 33 ms): call it from
a thread of its own, never from the control loop's, and as fast as it returns (a device is
asked for a single buffer, so what it returns is its latest frame). Frames come in BGR; they
leave as RGB. The capture time is taken on the robot's clock as the frame is handed over, so a
frame is at least as old as it is said to be plus the device's own exposure and transfer
(``CAP_PROP_POS_MSEC`` is the stream's own time, not the robot's: not used).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import cv2
import numpy as np

from drivers.camera import CameraFrame, CameraLost, make_frame


class OpenCvCamera:
    """One OpenCV capture as a :class:`~drivers.camera.CameraSource`."""

    def __init__(self, name: str, device: int | str, width: int, height: int,
                 calibration_epoch: str, clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.name = name
        self.device = device
        self.size = (height, width)
        self.calibration_epoch = calibration_epoch
        self._clock = clock
        self._capture: cv2.VideoCapture | None = None
        self._buffer: np.ndarray | None = None

    def open(self) -> None:
        """Raises:
            CameraLost: the device or file does not open, or gives frames of another size.
        """
        capture = cv2.VideoCapture(self.device)
        if not capture.isOpened():
            capture.release()
            raise CameraLost(f"{self.name}: {self.device!r} does not open")
        if self.live:  # a device can be asked; a file is what it is
            capture.set(cv2.CAP_PROP_FRAME_WIDTH, self.size[1])
            capture.set(cv2.CAP_PROP_FRAME_HEIGHT, self.size[0])
            # One buffer: a read gets the frame the device took last, not the oldest of the
            # four V4L2 queues by default (300-400 ms old at 30 fps, stamped as new).
            capture.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        shape = (int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)),
                 int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)))
        if shape != self.size:
            capture.release()
            raise CameraLost(f"{self.name}: {self.device!r} gives {shape[1]}x{shape[0]} frames, "
                             f"the manifest says {self.size[1]}x{self.size[0]}")
        self._capture = capture

    @property
    def live(self) -> bool:
        """A device (an index or a /dev path), not a recorded file."""
        return isinstance(self.device, int) or self.device.startswith("/dev/")

    def read(self) -> CameraFrame:
        """Raises:
            CameraLost: not open, or no frame (a device gone, a file at its end).
        """
        if self._capture is None:
            raise CameraLost(f"{self.name}: not open")
        ok, bgr = self._capture.read(self._buffer)
        t_capture = self._clock()
        if not ok or bgr is None:
            raise CameraLost(f"{self.name}: {self.device!r} gave no frame")
        self._buffer = bgr
        return make_frame(self.name, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), t_capture,
                          self.calibration_epoch)

    def close(self) -> None:
        capture, self._capture = self._capture, None
        if capture is not None:
            capture.release()
