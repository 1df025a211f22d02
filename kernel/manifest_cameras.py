"""``[[cameras]]``: the cell's cameras, one table each (docs/manifest.md, "Cameras").

Read while the manifest loads, like every other table: an unknown key, a value out of range, a
repeated name, an OpenCV camera without its device or a simulated one on a cell whose plant
warden does not run exits 2 naming ``cameras[i].key``, before anything starts.
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import StrEnum
from typing import Annotated, Any

import msgspec
from msgspec import Meta

from drivers.settings import KeyProblem
from kernel.config.cameras import GRACE_MAX_MS
from kernel.core.config import LossAction
from kernel.scenario.fields import Where
from kernel.shell.link_settings import PolicyProtocol, PolicySettings
from kernel.tables import read_table
from kernel.wire import ImageEncoding

SIM_CAMERAS = ("wrist_rgb", "scene_rgb")
"""The simulated cell's cameras (stubs/plant/cameras.py)."""
Pixels = Annotated[int, Meta(ge=16, le=4096)]
MAX_FRAME_AGE_MS = 10_000.0


class CameraKind(StrEnum):
    OPENCV = "opencv"
    """A V4L2/USB device (its index, or a path such as /dev/video0) or a video file."""
    SIM = "sim"
    """One of the simulated cell's cameras, rendered from its plant."""


class CameraSettings(msgspec.Struct, frozen=True, kw_only=True):
    name: Annotated[str, Meta(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")]
    """The observation key its frames go under (``wrist_rgb``, ``scene_rgb``)."""
    source: CameraKind
    device: Annotated[str, Meta(min_length=1, max_length=4096)] | None = None
    """OpenCV: a device index (``"0"``), a device path (``/dev/video0``) or a video file."""
    width: Pixels = 224
    height: Pixels = 224
    rate_hz: Annotated[float, Meta(ge=0.1, le=120.0)] = 10.0
    """How often a simulated camera renders; what a device is expected to deliver."""
    calibration_epoch: Annotated[str, Meta(min_length=1, max_length=64)] = "uncalibrated"
    encoding: ImageEncoding = ImageEncoding.RAW
    """How its frames travel: ``raw`` RGB (224×224: 147 KiB) or ``jpeg`` at ``jpeg_quality``
    (warden's protocol only: openpi takes arrays)."""
    jpeg_quality: Annotated[int, Meta(ge=1, le=100)] = 90
    on_loss: LossAction = LossAction.STOP
    """What losing this camera means: the phase stops at once (``stop``), or goes on with
    what was admitted for at most ``grace_ms`` (``continue``; kernel/core/cameras.py)."""
    grace_ms: Annotated[float, Meta(ge=0.0, le=GRACE_MAX_MS)] = 0.0
    max_frame_age_ms: Annotated[float, Meta(ge=1.0, le=MAX_FRAME_AGE_MS)] | None = None
    """A newest frame older than this is a lost camera (default: three frame periods, at most
    10 s)."""
    freeze_frames: Annotated[int, Meta(ge=0, le=600)] = 0
    """This many identical frames in a row is a frozen camera (0: not watched). Only for a
    real sensor, whose noise changes every frame; a rendered scene that stands still
    repeats itself."""

    @property
    def frame_age_limit_ms(self) -> float:
        return self.max_frame_age_ms if self.max_frame_age_ms is not None else min(
            3000.0 / self.rate_hz, MAX_FRAME_AGE_MS)

    @property
    def live_device(self) -> bool:
        """An OpenCV device (an index or a /dev path), whose read waits for its next frame;
        not a video file, which is read at ``rate_hz``."""
        device = self.device or ""
        return self.source is CameraKind.OPENCV and (device.isdigit()
                                                     or device.startswith("/dev/"))

    @property
    def opencv_device(self) -> int | str:
        """What OpenCV opens: an index for digits, else the path."""
        device = self.device or ""
        return int(device) if device.isdigit() else device

    def __post_init__(self) -> None:
        if self.source is CameraKind.OPENCV and self.device is None:
            raise KeyProblem("device", "an opencv camera needs its device (index, path or file)")
        if self.source is CameraKind.SIM and self.name not in SIM_CAMERAS:
            raise KeyProblem("name", f"the simulated cell's cameras are {', '.join(SIM_CAMERAS)}")
        if self.freeze_frames == 1:
            raise KeyProblem("freeze_frames", "a freeze is at least 2 identical frames (0: off)")
        if self.source is CameraKind.SIM and self.freeze_frames:
            raise KeyProblem("freeze_frames", "a rendered scene that stands still repeats "
                             "itself: freeze_frames is for a real camera")
        if self.on_loss is LossAction.CONTINUE and not self.grace_ms > 0:
            raise KeyProblem("grace_ms", 'on_loss = "continue" needs a positive grace_ms')
        if self.on_loss is LossAction.STOP and self.grace_ms > 0:
            raise KeyProblem("grace_ms", 'on_loss = "stop" stops at once: no grace_ms')

    def loss_entry(self) -> dict[str, Any]:
        """What the core knows of it: the scenario form of the ``cameras`` section."""
        entry: dict[str, Any] = {"name": self.name, "on_loss": str(self.on_loss)}
        if self.on_loss is LossAction.CONTINUE:
            entry["grace_ms"] = self.grace_ms
        return entry


def cameras_table(doc: Mapping[str, Any], where: Where, driver_name: str,
                  ) -> tuple[CameraSettings, ...]:
    """Every ``[[cameras]]`` entry, checked (module docstring).

    Raises:
        ScenarioError: naming the entry and key.
    """
    raw = doc.get("cameras", [])
    if not isinstance(raw, list):
        raise where.at("cameras").error("must be an array of tables ([[cameras]])")
    cameras: list[CameraSettings] = []
    for index, entry in enumerate(raw):
        here = where.at("cameras").at(index)
        if not isinstance(entry, Mapping):
            raise here.error("must be a table")
        camera = read_table(CameraSettings, entry, here)
        if camera.name in {c.name for c in cameras}:
            raise here.at("name").error(f"{camera.name!r} is named twice")
        if camera.source is CameraKind.SIM and driver_name != "sim":
            raise here.at("source").error(
                f"a simulated camera renders warden's own plant; the {driver_name} cell's "
                "plant runs in its emulator")
        cameras.append(camera)
    return tuple(cameras)


IMAGE_PROTOCOL = 3
"""The first version of warden's wire protocol whose observations carry frames."""


def check_cameras_travel(cameras: tuple[CameraSettings, ...], protocol: tuple[int, int],
                         policy: PolicySettings, where: Where) -> None:
    """Every camera's frames can reach the policy: over warden's protocol, every version the
    session may agree carries frames; over openpi's, each camera has the key the server reads
    it under, and travels as the array openpi takes.

    Raises:
        ScenarioError: naming the key.
    """
    if policy.protocol is PolicyProtocol.OPENPI:
        _check_openpi_images(cameras, policy, where)
    elif cameras and protocol[0] < IMAGE_PROTOCOL:
        raise where.at("session").at("protocol").error(
            f"frames travel from protocol {IMAGE_PROTOCOL} on: with [[cameras]], the range "
            f"must start at {IMAGE_PROTOCOL}, got {list(protocol)}")


def _check_openpi_images(cameras: tuple[CameraSettings, ...], policy: PolicySettings,
                         where: Where) -> None:
    mapped = dict(policy.openpi.images) if policy.openpi is not None else {}
    names = {camera.name for camera in cameras}
    for index, camera in enumerate(cameras):
        if camera.name not in mapped:
            raise where.at("policy").at("openpi").at("images").error(
                f"camera {camera.name!r} has no openpi key to travel under")
        if camera.encoding is not ImageEncoding.RAW:
            raise where.at("cameras").at(index).at("encoding").error(
                "openpi takes images as arrays: encoding must be \"raw\"")
    for name in mapped:
        if name not in names:
            raise where.at("policy").at("openpi").at("images").at(name).error(
                "no [[cameras]] entry of that name")
