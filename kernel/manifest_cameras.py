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
from kernel.scenario.fields import Where
from kernel.tables import read_table

SIM_CAMERAS = ("wrist_rgb", "scene_rgb")
"""The simulated cell's cameras (stubs/plant/cameras.py)."""
Pixels = Annotated[int, Meta(ge=16, le=4096)]


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
