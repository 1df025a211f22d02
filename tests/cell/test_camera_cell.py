"""The simulated cell seeing through cameras over warden's protocol 3: the wrist and scene
cameras rendered from the plant (one raw, one JPEG), every observation carrying both to the
reference server, which checks every frame and closes the link on one that is missing or not
what it claims. And a camera lost in the middle of a run: an OpenCV camera reading a recorded
video that ends, which the manifest says stops the phase."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from drivers.camera import frame_digest
from kernel.cli import main
from kernel.export import export_mcap
from tests.cell.harness import MANIFESTS, replays_identically, run_dir

pytestmark = pytest.mark.slow


def _with_cameras(directory: Path, cameras: str, cycles: int = 1,
                  timeout_s: float = 30.0, frames: str = "digests") -> Path:
    """sim-ur5e with ``cameras`` ([[cameras]] tables) and warden's protocol 3; nothing else
    changed (a rendered frame leaves about 8 ms old: bench/camera_latency.py)."""
    text = (MANIFESTS / "sim-ur5e.toml").read_text()
    for pattern, new in ((r"(?m)^protocol = \[1, 2\]", "protocol = [3, 3]"),
                         (r"(?m)^cycles = \d+", f"cycles = {cycles}"),
                         (r"(?m)^cycle_timeout_s = [0-9.]+", f"cycle_timeout_s = {timeout_s}"),
                         (r"(?m)^\[journal\]\n", f'[journal]\nframes = "{frames}"\n')):
        text, count = re.subn(pattern, new, text, count=1)
        assert count == 1, pattern
    path = directory / "cameras.toml"
    path.write_text(text + cameras + f'\n[operator]\nsocket = "{directory / "op.sock"}"\n')
    return path


def _run(manifest: Path, root: Path) -> tuple[int, dict[str, Any], Path]:
    code = main(["run", str(manifest), "--journal-dir", str(root)])
    directory = run_dir(root)
    return code, json.loads((directory / "summary.json").read_text()), directory


def _lines(directory: Path, name: str) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (directory / name).read_text().splitlines()]


RENDERED = '''
[[cameras]]
name = "wrist_rgb"
source = "sim"
rate_hz = 2.0

[[cameras]]
name = "scene_rgb"
source = "sim"
rate_hz = 2.0
encoding = "jpeg"
on_loss = "continue"
grace_ms = 500.0
'''


def test_the_cell_verifies_its_cycle_seeing_through_both_rendered_cameras(
        tmp_path: Path) -> None:
    code, summary, directory = _run(_with_cameras(tmp_path, RENDERED, frames="pixels"),
                                    tmp_path / "runs")
    link = summary["link"]
    assert code == 0, summary["cycles"]
    assert "protocol_violations" not in link and link["connects"] == 1, link
    # Every observation carried a raw 224×224 frame (150 528 bytes) and a JPEG one.
    assert link["bytes_out"] > link["observations_sent"] * 224 * 224 * 3, link
    journal = _lines(directory, "journal.jsonl")
    observations = [e for e in journal[1:] if e.get("kind") == "observation"]
    assert observations and all(len(o["frames"]) == 2 for o in observations)
    assert len({f["digest"] for o in observations for f in o["frames"]}) > 4  # it moved
    # frames = "pixels": each picture sent is kept once, as a PNG named by its digest.
    kept = summary["frames"]
    assert kept["error"] is None and kept["written"] + kept["dropped"] == len(
        {(f["camera"], f["digest"]) for o in observations for f in o["frames"]}), kept
    for frame in observations[-1]["frames"]:
        png = directory / "frames" / frame["camera"] / f"{frame['digest']}.png"
        rgb = cv2.cvtColor(cv2.imread(str(png)), cv2.COLOR_BGR2RGB)
        assert frame_digest(rgb) == frame["digest"]  # the picture the journal names
    assert not [line for line in _lines(directory, "decisions.jsonl")
                if line["kind"] == "camera"]  # never lost
    assert replays_identically(directory)
    # `warden export --mcap`: every kept picture is a CompressedImage on its camera's topic.
    counts = export_mcap(directory, tmp_path / "run.mcap")
    on_disk = {(f["camera"], f["digest"]) for o in observations for f in o["frames"]
               if (directory / "frames" / f["camera"] / f"{f['digest']}.png").is_file()}
    sent = [(f["camera"], f["digest"]) for o in observations for f in o["frames"]]
    for camera in ("wrist_rgb", "scene_rgb"):
        assert counts[f"/camera/{camera}"] == sum(
            1 for key in sent if key[0] == camera and key in on_disk) > 0


def _video(path: Path, frames: int) -> Path:
    """A recorded camera: ``frames`` 64×48 frames, each a little different."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for k in range(frames):
        writer.write(np.full((48, 64, 3), (k * 17) % 256, dtype=np.uint8))
    writer.release()
    return path


def test_a_camera_lost_mid_run_stops_the_phase_and_is_reported_back(tmp_path: Path) -> None:
    video = _video(tmp_path / "wrist.avi", 30)  # 3 s at 10 Hz, then the camera is gone
    cameras = f'''
[[cameras]]
name = "wrist_rgb"
source = "opencv"
device = "{video}"
width = 64
height = 48
rate_hz = 10.0
on_loss = "stop"
'''
    manifest = _with_cameras(tmp_path, cameras, timeout_s=12.0)
    _, _, directory = _run(manifest, tmp_path / "runs")
    lines = _lines(directory, "decisions.jsonl")
    cameras_seen = [(line["status"], line["on_loss"]) for line in lines
                    if line["kind"] == "camera"]
    assert ("lost", "stop") in cameras_seen, cameras_seen
    assert ("back", "stop") in cameras_seen  # the file was opened again and played
    held = [line for line in lines if line["kind"] == "transition"
            and line["machine"] == "fallback" and line.get("trigger") == "CAMERA_LOST"]
    assert held and held[0]["to"] == "SAFE_HOLD"
    lost_at = next(line["t"] for line in lines
                   if line["kind"] == "camera" and line["status"] == "lost")
    # Nothing was asked of the policy while the camera was down.
    back_at = next(line["t"] for line in lines
                   if line["kind"] == "camera" and line["status"] == "back" and line["t"] > lost_at)
    assert not [line for line in lines if line["kind"] == "request"
                and lost_at <= line["t"] < back_at]
    assert replays_identically(directory)
