"""Cameras, beside the arm's driver: what a camera source gives and how it fails.

A policy that sees needs frames, and warden needs to know of each frame when it was taken (on
the robot's clock, the one observations and admission use), what it showed (a digest the
journal can keep instead of the pixels) and which calibration it was taken under. A
:class:`CameraSource` is opened, read one frame at a time and closed; a source that can give no
frame raises :class:`CameraLost` naming itself. Two sources exist: OpenCV for V4L2/USB
cameras and video files (:mod:`drivers.opencv_camera`) and the simulated cell's MuJoCo
cameras, drawn from its plant's joints by a render process of their own
(:mod:`stubs.plant.cameras`).

A camera that keeps sending the same picture is as bad as a lost one, and harder to see:
:class:`FreezeWatch` tells one from a scene that merely stands still only for a real sensor
(its noise changes every frame), so it is for real cameras, not for a rendered scene.

The run reads them through kernel/shell/cameras.py (docs/architecture.md, "Cameras").
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


class CameraLost(Exception):
    """The camera gave no frame (unplugged, a file that ended, a device that failed)."""


@dataclass(frozen=True, slots=True, eq=False)
class CameraFrame:
    camera: str
    image: np.ndarray
    """H × W × 3, uint8, RGB, read-only."""
    t_capture_ns: int
    """The robot's clock when the frame was taken (its age counts from here)."""
    digest: str
    """:func:`frame_digest` of the image: what a journal records instead of the pixels."""
    calibration_epoch: str


def frame_digest(image: np.ndarray) -> str:
    """SHA-256 (first 128 bits) over the image's shape and its bytes."""
    contiguous = np.ascontiguousarray(image)
    digest = hashlib.sha256(repr(contiguous.shape).encode())
    digest.update(contiguous.tobytes())
    return digest.hexdigest()[:32]


def make_frame(camera: str, image: np.ndarray, t_capture_ns: int,
               calibration_epoch: str) -> CameraFrame:
    """A frame of an RGB uint8 image (copied and made read-only: the source reuses buffers).

    Raises:
        CameraLost: the image is not H × W × 3 uint8.
    """
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise CameraLost(f"{camera}: a frame of {image.dtype} {image.shape}, not H x W x 3 uint8")
    owned = np.array(image, copy=True)
    owned.setflags(write=False)
    return CameraFrame(camera, owned, t_capture_ns, frame_digest(owned), calibration_epoch)


class CameraSource(Protocol):
    """A camera: ``open`` before the first ``read``, ``close`` once (also after a failure).

    ``read`` gives the newest frame and raises :class:`CameraLost` when there is none to give.
    """

    name: str

    def open(self) -> None: ...

    def read(self) -> CameraFrame: ...

    def close(self) -> None: ...


@runtime_checkable
class TriggeredSource(CameraSource, Protocol):
    """A camera that takes a picture when asked (a rendered one): ``trigger`` returns at once,
    and ``read`` gives the new frame once it is there (the newest until then)."""

    def trigger(self) -> None: ...


class FreezeWatch:
    """Consecutive frames with the same digest: ``repeats`` in a row is a frozen camera."""

    def __init__(self, repeats: int) -> None:
        if repeats < 2:
            raise ValueError("a freeze is at least two identical frames")
        self.repeats = repeats
        self._last: str | None = None
        self._count = 0

    def frozen(self, frame: CameraFrame) -> bool:
        """Whether this frame makes the camera frozen (it stays so until a frame differs)."""
        self._count = self._count + 1 if frame.digest == self._last else 1
        self._last = frame.digest
        return self._count >= self.repeats
