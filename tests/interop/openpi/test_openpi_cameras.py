"""The shipped openpi manifest (``manifests/sim-openpi.toml``) run as an integrator would: an
unmodified openpi ``WebsocketPolicyServer`` in its own venv, serving a scripted policy that
drives the arm from the observed state to the pre-insert pose, and that raises (its traceback
ends the link) unless every observation carries both cameras' 224×224 uint8 images under the
manifest's keys, changing as the arm moves. The cycles verify; the journal keeps every frame's
digest and replays identically."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from kernel.app.compose import cell_context
from kernel.cli import main
from kernel.manifest import load_manifest
from stubs.cell.reference import policy_goal
from tests.cell.harness import MANIFESTS, replays_identically, run_dir
from tests.interop.openpi.test_openpi_live import start

pytestmark = pytest.mark.slow
SHIPPED = MANIFESTS / "sim-openpi.toml"
IMAGES = ("observation/wrist_image:224x224", "observation/image:224x224")


def _pointed_at(directory: Path, port: int, cycles: int) -> Path:
    """The shipped manifest, its port and cycle count changed (nothing else)."""
    text = SHIPPED.read_text()
    for pattern, new in ((r"(?m)^port = 8000", f"port = {port}"),
                         (r"(?m)^cycles = \d+", f"cycles = {cycles}")):
        text, count = re.subn(pattern, new, text, count=1)
        assert count == 1, pattern
    path = directory / "sim-openpi.toml"
    path.write_text(text + f'\n[operator]\nsocket = "{directory / "operator.sock"}"\n')
    return path


def _server_options() -> list[str]:
    goal = policy_goal(cell_context(load_manifest(SHIPPED)))
    # 0.1 rad/s at 20 ms a step: the policy starts each chunk from the state it was sent, and
    # the arm lags its commands by some mrad at speed; at 0.15 rad/s the lag alone came to
    # 10.2-10.7 mrad, past the approach's max_projection (10), and such chunks were INFEASIBLE.
    return ["--dim", "6", "--horizon", "25", "--step", "0.002",
            "--goal", *(f"{v:.9f}" for v in goal),
            *(arg for image in IMAGES for arg in ("--image", image))]


def test_the_shipped_openpi_manifest_verifies_its_cycles_with_both_cameras(
        tmp_path: Path) -> None:
    for port in start(*_server_options()):
        code = main(["run", str(_pointed_at(tmp_path, port, 2)),
                     "--journal-dir", str(tmp_path / "runs")])
    directory = run_dir(tmp_path / "runs")
    summary = json.loads((directory / "summary.json").read_text())
    link = summary["link"]
    assert code == 0, summary["cycles"]
    assert summary["cycles"]["verified"] == 2
    assert link["connects"] == 1 and "protocol_violations" not in link, link
    # Two 224×224 RGB frames in every observation (openpi's own msgpack_numpy layout).
    assert link["bytes_out"] >= link["observations_sent"] * 2 * 224 * 224 * 3, link
    journal = [json.loads(line) for line in (directory / "journal.jsonl").read_text().splitlines()]
    observations = [e for e in journal[1:] if e.get("kind") == "observation"]
    assert observations and all(
        [f["camera"] for f in o["frames"]] == ["wrist_rgb", "scene_rgb"] for o in observations)
    digests = {f["digest"] for o in observations for f in o["frames"]}
    assert len(digests) > 4  # the cameras saw the arm move
    assert journal[0]["cameras"] == [
        {"name": "wrist_rgb", "on_loss": "stop"},
        {"name": "scene_rgb", "on_loss": "continue", "grace_ms": 500.0}]
    assert replays_identically(directory)
