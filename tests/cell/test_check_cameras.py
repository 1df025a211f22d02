"""``[[cameras]]``: read while the manifest loads (a mistake exits 2 naming it, before anything
starts), and ``warden check`` reads each OpenCV camera for a moment: a recorded video stands in
for a device, through the same OpenCV calls."""

from __future__ import annotations

import asyncio
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from kernel.app.check_cameras import camera_rows
from kernel.manifest import ManifestError, load_manifest
from tests.cell.harness import MANIFESTS

SIM = (MANIFESTS / "sim-ur5e.toml").read_text()


def _with_cameras(tmp_path: Path, cameras: str, base: str = SIM) -> Path:
    path = tmp_path / "cell.toml"
    path.write_text(base.replace("[policy]\n", f"{cameras}\n[policy]\n", 1))
    return path


def _video(path: Path, frames: int, width: int = 64, height: int = 48,
           changing: bool = True) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (width, height))
    for k in range(frames):
        writer.write(np.full((height, width, 3), (40 * k if changing else 90, 80, 0), np.uint8))
    writer.release()
    return path


@pytest.mark.parametrize(("cameras", "says"), [
    ('[[cameras]]\nname = "wrist_rgb"\nsource = "opencv"\n',
     "cameras[0].device: an opencv camera needs its device"),
    ('[[cameras]]\nname = "top"\nsource = "sim"\n',
     "cameras[0].name: the simulated cell's cameras are wrist_rgb, scene_rgb"),
    ('[[cameras]]\nname = "wrist_rgb"\nsource = "sim"\n[[cameras]]\nname = "wrist_rgb"\n'
     'source = "sim"\n', "cameras[1].name: 'wrist_rgb' is named twice"),
    ('[[cameras]]\nname = "wrist_rgb"\nsource = "sim"\nwidth = 8\n', "cameras[0].width"),
    ('[[cameras]]\nname = "wrist_rgb"\nsource = "sim"\nexposure = 3\n',
     "cameras[0].exposure: unknown key"),
    ('[[cameras]]\nname = "wrist_rgb"\nsource = "usb"\n', "cameras[0].source"),
])
def test_a_camera_the_cell_cannot_have_is_refused_at_load(tmp_path: Path, cameras: str,
                                                         says: str) -> None:
    with pytest.raises(ManifestError, match=re.escape(says)):
        load_manifest(_with_cameras(tmp_path, cameras))


def test_cameras_that_are_not_tables_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "cell.toml"
    path.write_text("cameras = 3\n" + SIM)
    with pytest.raises(ManifestError, match=re.escape("cameras: must be an array of tables")):
        load_manifest(path)


def test_a_simulated_camera_needs_warden_to_run_the_plant(tmp_path: Path) -> None:
    rtde = (MANIFESTS / "sim-ur5e-rtde.toml").read_text()
    path = _with_cameras(tmp_path, '[[cameras]]\nname = "wrist_rgb"\nsource = "sim"\n', rtde)
    with pytest.raises(ManifestError, match=re.escape("cameras[0].source: a simulated camera")):
        load_manifest(path)


def test_check_reads_each_opencv_camera_and_says_what_it_got(tmp_path: Path) -> None:
    moving = _video(tmp_path / "moving.avi", 12)
    frozen = _video(tmp_path / "frozen.avi", 12, changing=False)
    path = _with_cameras(tmp_path, f'''
[[cameras]]
name = "wrist_rgb"
source = "opencv"
device = "{moving}"
width = 64
height = 48

[[cameras]]
name = "scene_rgb"
source = "opencv"
device = "{frozen}"
width = 64
height = 48

[[cameras]]
name = "side"
source = "opencv"
device = "{tmp_path / 'unplugged.avi'}"
''')
    rows = {row.name: row for row in asyncio.run(camera_rows(load_manifest(path)))}
    assert rows["camera wrist_rgb"].verdict == "READY", rows["camera wrist_rgb"]
    assert rows["camera wrist_rgb"].measured.startswith("12 frames")
    assert rows["camera scene_rgb"].verdict == "NOT READY"
    assert "frozen" in rows["camera scene_rgb"].reason
    assert rows["camera side"].verdict == "NOT READY"
    assert "does not open" in rows["camera side"].reason


def test_a_simulated_camera_is_not_exercised_by_check(tmp_path: Path) -> None:
    path = _with_cameras(tmp_path, '[[cameras]]\nname = "wrist_rgb"\nsource = "sim"\n')
    [row] = asyncio.run(camera_rows(load_manifest(path)))
    assert row.verdict == "NOT EXERCISED" and "plant" in row.reason
