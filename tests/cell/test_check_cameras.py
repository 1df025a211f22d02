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

SIM = (MANIFESTS / "sim-ur5e.toml").read_text().replace(
    "protocol = [1, 2]", "protocol = [3, 3]").replace(
    '"joint_pos", "wrench"]', '"side_rgb", "joint_pos", "wrench"]')
"""The simulated cell on protocol 3 (frames travel), with a third camera's key."""


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
    ('[[cameras]]\nname = "thermal_ir"\nsource = "opencv"\ndevice = "0"\n',
     "cameras[0].name: 'thermal_ir' is not one of session.observation_keys"),
    ('[[cameras]]\nname = "wrist_rgb"\nsource = "sim"\nfreeze_frames = 5\n',
     "cameras[0].freeze_frames: a rendered scene that stands still"),
    ('[[cameras]]\nname = "wrist_rgb"\nsource = "sim"\non_loss = "continue"\n',
     "cameras[0].grace_ms: on_loss = \"continue\" needs a positive grace_ms"),
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


def test_frames_need_protocol_3_a_wall_clock_and_an_openpi_key(tmp_path: Path) -> None:
    camera = '[[cameras]]\nname = "wrist_rgb"\nsource = "sim"\n'
    old = SIM.replace("protocol = [3, 3]", "protocol = [1, 3]")
    with pytest.raises(ManifestError, match=re.escape(
            "session.protocol: frames travel from protocol 3 on")):
        load_manifest(_with_cameras(tmp_path, camera, old))
    virtual = SIM.replace('clock = "wall"', 'clock = "virtual"')
    with pytest.raises(ManifestError, match=re.escape("cell.clock: a virtual-clock run has no "
                                                      "cameras")):
        load_manifest(_with_cameras(tmp_path, camera, virtual))
    openpi = (MANIFESTS / "sim-openpi.toml").read_text()
    unmapped = openpi.replace('wrist_rgb = "observation/wrist_image"\n', "")
    with pytest.raises(ManifestError, match=re.escape(
            "policy.openpi.images: camera 'wrist_rgb' has no openpi key")):
        load_manifest(_with_cameras(tmp_path, "", unmapped))
    jpeg = openpi.replace('name = "scene_rgb"\n', 'name = "scene_rgb"\nencoding = "jpeg"\n')
    with pytest.raises(ManifestError, match=re.escape("cameras[1].encoding: openpi takes")):
        load_manifest(_with_cameras(tmp_path, "", jpeg))
    stray = openpi.replace('scene_rgb = "observation/image"\n',
                           'scene_rgb = "observation/image"\nside = "observation/side"\n')
    with pytest.raises(ManifestError, match=re.escape("policy.openpi.images.side: no "
                                                      "[[cameras]] entry")):
        load_manifest(_with_cameras(tmp_path, "", stray))


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
name = "side_rgb"
source = "opencv"
device = "{tmp_path / 'unplugged.avi'}"
''')
    rows = {row.name: row for row in asyncio.run(camera_rows(load_manifest(path)))}
    assert rows["camera wrist_rgb"].verdict == "READY", rows["camera wrist_rgb"]
    assert rows["camera wrist_rgb"].measured.startswith("12 frames")
    assert rows["camera scene_rgb"].verdict == "NOT READY"
    assert "frozen" in rows["camera scene_rgb"].reason
    assert rows["camera side_rgb"].verdict == "NOT READY"
    assert "does not open" in rows["camera side_rgb"].reason


def test_a_simulated_camera_is_not_exercised_by_check(tmp_path: Path) -> None:
    path = _with_cameras(tmp_path, '[[cameras]]\nname = "wrist_rgb"\nsource = "sim"\n')
    [row] = asyncio.run(camera_rows(load_manifest(path)))
    assert row.verdict == "NOT EXERCISED" and "plant" in row.reason


def test_a_virtual_clock_asked_for_on_the_command_line_is_refused_with_cameras(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from kernel.cli import main

    path = _with_cameras(tmp_path, '[[cameras]]\nname = "wrist_rgb"\nsource = "sim"\n')
    assert main(["run", str(path), "--clock", "virtual", "--no-journal"]) == 2
    assert "--clock virtual: " in capsys.readouterr().err
