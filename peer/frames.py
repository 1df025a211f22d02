"""What a policy server checks of an observation's camera frames (protocol 3).

A server that needs cameras must be sure it got them: every camera it was started with
(``--camera NAME:WxH``) exactly once, nothing else, at its size (a JPEG's declared size is read
from its header before anything is decoded, and it may be no larger than the raw pixels), a raw
frame's digest the one its bytes give, and none taken before the observation's own time (which
is its oldest frame's). Anything else is a
protocol violation: the client broke its handshake's promise of those observation keys.
A JPEG is decoded by the codec the server hands in (the reference server's is OpenCV's); a
server without one (the LeRobot sidecar's small venv) takes raw frames only.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from peer.protocol import IMAGE_VERSION, Image, Observation


class ImageProblem(ValueError):
    """An observation's frames are not what the server needs."""


@dataclass(frozen=True, slots=True)
class CameraShape:
    name: str
    width: int
    height: int

    @classmethod
    def parse(cls, text: str) -> CameraShape:
        """``NAME:WxH``."""
        name, _, size = text.partition(":")
        width, _, height = size.partition("x")
        if not name or not width.isdigit() or not height.isdigit():
            raise ValueError(f"a camera is NAME:WxH, got {text!r}")
        return cls(name, int(width), int(height))

    @property
    def raw_bytes(self) -> int:
        return self.width * self.height * 3


JpegDecoder = Callable[[bytes], np.ndarray | None]
"""A JPEG file → its RGB pixels (H×W×3 uint8), or None when it does not decode."""


def check_images(observation: Observation, cameras: tuple[CameraShape, ...], version: int,
                 decode_jpeg: JpegDecoder | None = None) -> list[np.ndarray]:
    """The frames' pixels (RGB, H×W×3), in the order of ``cameras``; JPEG frames are refused
    when ``decode_jpeg`` is None.

    Raises:
        ImageProblem: naming the camera and what is wrong.
    """
    if version < IMAGE_VERSION:
        if observation.images:
            raise ImageProblem(f"frames need protocol {IMAGE_VERSION}, agreed {version}")
        return []
    by_name = {image.camera: image for image in observation.images}
    if len(by_name) != len(observation.images):
        raise ImageProblem("a camera's frame appears twice")
    unknown = set(by_name) - {camera.name for camera in cameras}
    if unknown:
        raise ImageProblem(f"frames of cameras not in the session: {sorted(unknown)}")
    pixels = []
    for camera in cameras:
        image = by_name.get(camera.name)
        if image is None:
            raise ImageProblem(f"no frame of camera {camera.name}")
        if image.t_capture < observation.t_event:
            raise ImageProblem(f"{camera.name}: taken before the observation's time (its age "
                               "would count from a later instant than the frame's)")
        pixels.append(_pixels(image, camera, decode_jpeg))
    return pixels


def _pixels(image: Image, camera: CameraShape, decode_jpeg: JpegDecoder | None) -> np.ndarray:
    if (image.width, image.height) != (camera.width, camera.height):
        raise ImageProblem(f"{camera.name}: {image.width}x{image.height}, expected "
                           f"{camera.width}x{camera.height}")
    if image.encoding == "raw":
        if len(image.data) != camera.raw_bytes:
            raise ImageProblem(f"{camera.name}: {len(image.data)} bytes for a raw "
                               f"{camera.width}x{camera.height} RGB frame")
        rgb = np.frombuffer(image.data, dtype=np.uint8).reshape(camera.height, camera.width, 3)
        if _digest(rgb) != image.digest:
            raise ImageProblem(f"{camera.name}: the bytes do not give the frame's digest")
        return rgb
    if decode_jpeg is None:
        raise ImageProblem(f"{camera.name}: this server takes raw frames only, not JPEG")
    # Nothing is decoded before it is known to be a JPEG of the camera's size, no larger than
    # its raw pixels: a hostile file that declares 14000 x 14000 would otherwise cost seconds
    # and a gigabyte (and OpenCV decodes any format it is given).
    if len(image.data) > camera.raw_bytes or jpeg_size(image.data) != (camera.width,
                                                                         camera.height):
        raise ImageProblem(f"{camera.name}: not a {camera.width}x{camera.height} JPEG")
    rgb = decode_jpeg(image.data)
    if rgb is None or rgb.shape != (camera.height, camera.width, 3):
        raise ImageProblem(f"{camera.name}: not a {camera.width}x{camera.height} JPEG")
    return rgb


_SOF = frozenset({0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF})
"""The start-of-frame markers: each carries the image's height and width."""


def jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a JPEG's frame header, read from its markers without decoding;
    None for anything that is not a JPEG, or whose header is cut or malformed."""
    if data[:3] != b"\xff\xd8\xff":
        return None
    at = 2
    while at + 4 <= len(data):
        if data[at] != 0xFF:
            return None
        marker = data[at + 1]
        if marker == 0xFF:  # a fill byte before the marker
            at += 1
            continue
        if marker in _SOF:
            if at + 9 > len(data):
                return None
            height = int.from_bytes(data[at + 5:at + 7], "big")
            width = int.from_bytes(data[at + 7:at + 9], "big")
            return width, height
        length = int.from_bytes(data[at + 2:at + 4], "big")
        if length < 2:
            return None
        at += 2 + length
    return None


def _digest(rgb: np.ndarray) -> str:
    """SHA-256 over the shape's text and the bytes, first 128 bits (docs/protocol.md)."""
    digest = hashlib.sha256(repr(rgb.shape).encode())
    digest.update(rgb.tobytes())
    return digest.hexdigest()[:32]
