"""Capture the bytes an unmodified openpi server sends (run in the openpi venv, not warden's).

    python tests/interop/openpi/capture_frames.py tests/interop/openpi/frames

Serves a scripted ``BasePolicy`` through ``openpi_server.WebsocketPolicyServer`` on loopback,
connects with a plain websocket client, sends observations packed by openpi's own
``msgpack_numpy``, and writes every frame the server sent, byte for byte, with a provenance
file naming the package versions. The frames in ``frames/`` were made this way; warden's codec
tests (tests/interop/openpi/test_openpi_wire.py) decode them. The third observation makes the
policy raise, so the server's traceback text frame and its close code are captured too.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import importlib.metadata
import json
import socket
import sys
import threading
from pathlib import Path

import numpy as np
import websockets
import websockets.asyncio.client as ws_client
from openpi_client import base_policy, msgpack_numpy
from openpi_server import WebsocketPolicyServer

HORIZON, DIM = 10, 7
METADATA = {"reset_pose": [0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0, 0.0]}


class Scripted(base_policy.BasePolicy):
    """Actions that ramp from the observed state; the third call fails on purpose."""

    def __init__(self) -> None:
        self.calls = 0

    def infer(self, obs: dict) -> dict:
        self.calls += 1
        if self.calls == 3:
            raise RuntimeError("scripted failure: the third request")
        state = np.asarray(obs["observation/state"], dtype=np.float32)
        ramp = np.linspace(0.0, 0.01, HORIZON, dtype=np.float32)[:, None]
        return {"actions": state[None, :DIM] + ramp}


def observation(step: int) -> dict:
    rng = np.random.default_rng(step)
    return {
        "observation/image": rng.integers(0, 255, (8, 8, 3), dtype=np.uint8),
        "observation/wrist_image": rng.integers(0, 255, (8, 8, 3), dtype=np.uint8),
        "observation/state": np.full(8, 0.1 * step, dtype=np.float32),
        "prompt": "insert the peg",
    }


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


async def capture(port: int) -> list[tuple[str, bytes | str]]:
    frames: list[tuple[str, bytes | str]] = []
    async with ws_client.connect(f"ws://127.0.0.1:{port}", compression=None,
                                 max_size=None) as link:
        frames.append(("metadata.msgpack", await link.recv()))
        for step in (1, 2, 3):
            await link.send(msgpack_numpy.packb(observation(step)))
            frames.append((f"reply{step}.{'txt' if step == 3 else 'msgpack'}", await link.recv()))
        with contextlib.suppress(websockets.ConnectionClosed):  # 1011 after the traceback
            await link.recv()
        frames.append(("close_code.txt", str(link.close_code)))
    frames.append(("observation1.msgpack", msgpack_numpy.packb(observation(1))))
    return frames


def main(out: Path) -> None:
    port = free_port()
    server = WebsocketPolicyServer(Scripted(), host="127.0.0.1", port=port, metadata=METADATA)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    frames = asyncio.run(_with_retry(port))
    out.mkdir(parents=True, exist_ok=True)
    digests = {}
    for name, data in frames:
        raw = data.encode() if isinstance(data, str) else data
        if name == "reply3.txt":  # the traceback names this machine's paths: keep its shape
            raw = _strip_paths(raw)
        (out / name).write_bytes(raw)
        digests[name] = hashlib.sha256(raw).hexdigest()
    versions = {name: importlib.metadata.version(name) for name in
                ("openpi-client", "openpi-server", "msgpack", "numpy", "websockets")}
    provenance = {"script": "tests/interop/openpi/capture_frames.py", "python": sys.version,
                  "packages": versions, "sha256": digests}
    (out / "provenance.json").write_text(json.dumps(provenance, indent=2) + "\n")


def _strip_paths(text: bytes) -> bytes:
    lines = text.decode().splitlines(keepends=True)
    return "".join(line.split('File "')[0] + 'File "<site-packages>"' + line.split('"', 2)[2]
                   if 'File "' in line else line for line in lines).encode()


async def _with_retry(port: int) -> list[tuple[str, bytes | str]]:
    for _ in range(50):
        try:
            return await capture(port)
        except OSError:
            await asyncio.sleep(0.1)
    raise SystemExit(f"no openpi server on port {port}")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
