"""The run's cameras from the manifest's ``[[cameras]]``: OpenCV devices and files through the
driver layer, the simulated cell's cameras through the world that renders them (a stand-in,
reached through the world object, never imported here)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Protocol, runtime_checkable

from drivers.camera import CameraFrame, CameraSource
from drivers.opencv_camera import OpenCvCamera
from kernel.app.device import World
from kernel.manifest import Manifest, ManifestError
from kernel.manifest_cameras import CameraKind, CameraSettings
from kernel.settings import FrameRecord
from kernel.shell.cameras import CameraHub
from kernel.shell.frame_store import FrameStore


@runtime_checkable
class RenderingWorld(Protocol):
    """A simulated world that renders its cell's cameras."""

    def sim_camera(self, camera: CameraSettings, clock: Callable[[], int]) -> CameraSource: ...


def camera_hub(manifest: Manifest, world: World, clock: Callable[[], int],
               keep: Callable[[CameraFrame], None] | None = None) -> CameraHub | None:
    """The hub of the manifest's cameras, their frames stamped by ``clock`` (the run's), each
    frame sent given to ``keep``; None without cameras. Nothing is opened until the hub
    starts.

    Raises:
        ManifestError: a simulated camera in a world that renders none.
    """
    if not manifest.cameras:
        return None
    sources: dict[str, CameraSource] = {}
    for index, camera in enumerate(manifest.cameras):
        if camera.source is CameraKind.OPENCV:
            sources[camera.name] = OpenCvCamera(camera.name, camera.opencv_device, camera.width,
                                                camera.height, camera.calibration_epoch, clock)
        elif isinstance(world, RenderingWorld):
            sources[camera.name] = world.sim_camera(camera, clock)
        else:
            raise ManifestError(f"{manifest.path}: cameras[{index}].source: this world renders "
                                "no simulated camera")
    return CameraHub(manifest.cameras, sources, keep)


def frame_store(manifest: Manifest, run_directory: Path | None) -> FrameStore | None:
    """Where the frames' pictures are kept, when ``[journal] frames = "pixels"`` and the run
    has a directory (None otherwise: the journal keeps their digests)."""
    if not manifest.cameras or run_directory is None or (
            manifest.journal.frames is not FrameRecord.PIXELS):
        return None
    return FrameStore(run_directory / "frames")
