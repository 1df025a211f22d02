"""warden's openpi codec against openpi's own, unmodified server, running in its own venv."""

from __future__ import annotations

import asyncio
import socket
import subprocess
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import websockets.asyncio.client as ws_client

from kernel.openpi_wire import decode_metadata, decode_reply, encode_observation
from tests.interop.openpi.environment import openpi_python

SERVER = Path(__file__).with_name("serve_scripted.py")


def start(*options: str) -> Iterator[int]:
    port = free_port()
    server = subprocess.Popen([str(openpi_python()), str(SERVER), "--port", str(port), *options],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        wait_healthy(port, server)
        yield port
    finally:
        server.terminate()
        server.wait(timeout=10)


def wait_healthy(port: int, server: subprocess.Popen[bytes]) -> None:
    for _ in range(300):
        if server.poll() is not None:
            pytest.fail(f"the openpi server exited: {server.stderr.read().decode()[-2000:]}")
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=1) as answer:
                if answer.status == 200:
                    return
        except OSError:
            pass
        time.sleep(0.05)
    pytest.fail("the openpi server never answered /healthz")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def scripted() -> Iterator[int]:
    yield from start("--fail-on", "3", "--goal", "0.5", "0.5", "0.5", "0.5", "0.5", "0.5")


def observation(state: np.ndarray) -> bytes:
    image = np.zeros((224, 224, 3), dtype=np.uint8)
    return encode_observation({"observation/image": image, "observation/wrist_image": image,
                               "observation/state": state.astype(np.float32),
                               "prompt": "insert the peg"})


async def exchange(port: int, count: int) -> tuple[list[bytes | str], int | None]:
    frames: list[bytes | str] = []
    async with ws_client.connect(f"ws://127.0.0.1:{port}", max_size=None) as link:
        frames.append(await link.recv())
        for _ in range(count):
            await link.send(observation(np.zeros(6)))
            frames.append(await link.recv())
        if isinstance(frames[-1], str):  # openpi closes with 1011 after a traceback
            await link.wait_closed()
        return frames, link.close_code


def test_warden_reads_the_metadata_and_each_reply_of_the_real_server(scripted: int) -> None:
    frames, _ = asyncio.run(exchange(scripted, 2))
    metadata = decode_metadata(frames[0])
    assert metadata.value == {"policy": "scripted", "dim": 6}
    for raw in frames[1:]:
        reply = decode_reply(raw, action_dim=6, max_horizon=20)
        # The scripted policy steps 0.002 rad per action from the state towards 0.5.
        np.testing.assert_allclose(reply.actions[:, 0], 0.002 * np.arange(1, 21), atol=1e-6)


def test_a_server_side_exception_is_a_text_frame_then_close_1011() -> None:
    for port in start("--fail-on", "1"):
        frames, code = asyncio.run(exchange(port, 1))
        assert isinstance(frames[1], str) and "scripted failure on request 1" in frames[1]
        assert code == 1011
