"""Observation-to-admitted latency with two 224×224 cameras, next to joint-only, in one run.

A real core (the wire tests' loopback gateway, tests/wire/harness.py) and warden's real client
talk to the reference policy server (in process, over loopback websockets, protocol 3), whose
inference is instant, so what is measured is what cameras add: asking the rendered cameras for
a picture (each drawn by its own render process, as in the simulated cell), waiting for it,
encoding it, sending two frames, the server checking both (digest over the raw pixels, or a
JPEG decode), and the chunk coming back to admission. Three rows, each ``--seconds`` long:

- ``joint-only``: no camera, no frame;
- ``2 x 224x224 raw``: both cameras, raw RGB (147 KiB each);
- ``2 x 224x224 jpeg``: both cameras, JPEG at quality 90.

For every admitted chunk: its observation's age at admission (from the oldest frame's capture,
the age the gates judge), and how old the frames already were when the observation left.
Figures are printed, never asserted; compare the rows of one run (this machine is shared).

    .venv/bin/python bench/camera_latency.py [--seconds 6]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make the repository importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np

from kernel import wire
from kernel.core.events import ObservationEvent
from kernel.manifest_cameras import CameraKind, CameraSettings
from kernel.shell.cameras import CameraHub
from peer.frames import CameraShape
from stubs.plant.cameras import SIM_SPECS, RenderedCameras, render_model
from stubs.policy_server import LatencyModel
from tests.wire.harness import LoopbackGateway, running, server_config

NAMES = ("wrist_rgb", "scene_rgb")
SIZE = 224
SECTION = [{"name": name, "on_loss": "stop"} for name in NAMES]


def _rendered(gateway: LoopbackGateway) -> tuple[dict[str, object], list[RenderedCameras]]:
    """Both cameras, each its own renderer, of the cell's arm turning slowly."""
    qpos0 = render_model(tuple(SIM_SPECS.values())).qpos0.copy()
    start = gateway.now_ns()

    def qpos() -> np.ndarray:
        q = qpos0.copy()
        q[0] += 0.2 * (gateway.now_ns() - start) / 1e9  # the base turns: every frame differs
        return q

    renderers = [RenderedCameras((SIM_SPECS[name],), 2.0, qpos, "cal-12", gateway.now_ns)
                 for name in NAMES]
    return {name: r.camera(name) for name, r in zip(NAMES, renderers, strict=True)}, renderers


async def _row(encoding: wire.ImageEncoding | None, seconds: float) -> dict[str, list[float]]:
    cameras = encoding is not None
    gateway = LoopbackGateway("FREE_SPACE", {"request_retry_ms": 40}, protocol=(3, 3),
                              cameras=SECTION if cameras else None)
    hub = None
    if cameras:
        sources, _ = _rendered(gateway)
        settings = tuple(CameraSettings(name=name, source=CameraKind.SIM, rate_hz=2.0,
                                        encoding=encoding) for name in NAMES)
        hub = CameraHub(settings, sources)  # type: ignore[arg-type]
        hub.start()
        await asyncio.to_thread(hub.wait_first_frames)
    shapes = tuple(CameraShape(name, SIZE, SIZE) for name in NAMES) if cameras else ()
    server = server_config(latency=LatencyModel(0.0, 0.0), cameras=shapes)
    try:
        async with running(server, gateway, cameras=hub):
            await asyncio.sleep(seconds)
    finally:
        if hub is not None:
            await asyncio.to_thread(hub.stop)
    ages = [float(line.observation_age_ms) for line in gateway.admitted()
            if line.observation_age_ms is not None]
    frame_ages = [(o.t - min(f.t_capture for f in o.frames)) / 1e6 for o in gateway.events
                  if isinstance(o, ObservationEvent) and o.frames]
    return {"age": ages, "frames": frame_ages}


def _figures(values: list[float]) -> str:
    if not values:
        return "-"
    p50, p95 = np.percentile(values, [50, 95])
    return f"p50 {p50:6.1f}  p95 {p95:6.1f}  (n={len(values)})"


async def main_async(seconds: float) -> None:
    rows = {"joint-only": None, f"2 x {SIZE}x{SIZE} raw": wire.ImageEncoding.RAW,
            f"2 x {SIZE}x{SIZE} jpeg": wire.ImageEncoding.JPEG}
    results = {name: await _row(encoding, seconds) for name, encoding in rows.items()}
    base = np.percentile(results["joint-only"]["age"], 50) if results["joint-only"]["age"] else 0
    print(f"observation age at admission, ms (reference server, instant inference, "
          f"{seconds:g} s each)")
    for name, result in results.items():
        ratio = (f"  x{np.percentile(result['age'], 50) / base:5.1f} joint-only's p50"
                 if base and result["age"] else "")
        print(f"  {name:18s} {_figures(result['age'])}{ratio}")
    print("frame age when the observation left, ms")
    for name, result in results.items():
        if result["frames"]:
            print(f"  {name:18s} {_figures(result['frames'])}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=6.0)
    asyncio.run(main_async(parser.parse_args().seconds))


if __name__ == "__main__":
    main()
