"""Processes for the sidecar's tests: the stand-in LeRobot server and the sidecar, each in the
sidecar's venv (``tools/venvs.py``), and a robot side made of warden's own codec
(``kernel/wire.py``, ``assurance/handshake.py``, ``assurance/envelope.py``), never ``peer``'s.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import ssl
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import msgspec
import numpy as np
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

from assurance.envelope import Chunk, MalformedChunk, decode_wire_chunk
from assurance.handshake import ClientHello, HandshakeVerdict, evaluate
from assurance.reasons import ReasonCode
from drivers.camera import frame_digest
from kernel import wire
from tools.venvs import ROOT, sidecar_python

HERE = Path(__file__).parent
CAPTURED = HERE / "captured"
PROVENANCE = json.loads((CAPTURED / "provenance.json").read_text())
JOINTS = tuple(PROVENANCE["features"]["observation.state"]["names"])
CAMERAS = (("wrist_rgb", "wrist"), ("scene_rgb", "scene"))
SIDE = 224
OBSERVATION_KEYS = ("wrist_rgb", "scene_rgb", "joint_pos")
CHECKPOINT = "lerobot-act:random-seed-20261129"
FPS = 30


def sidecar_toml(lerobot_port: int, listen: str = "", **lerobot: Any) -> str:
    settings = {"server": f"127.0.0.1:{lerobot_port}", "policy_type": "act",
                "pretrained_name_or_path": "build/lerobot-act", "actions_per_chunk": 50,
                "fps": FPS, "reply_timeout_s": 5.0, **lerobot}
    lines = [f"joints = {json.dumps(list(JOINTS))}", "", "[lerobot]",
             *(f"{key} = {json.dumps(value)}" for key, value in settings.items()), "",
             "[listen]", "port = 0", listen, "",
             "[offer]", f'policy_checkpoint = "{CHECKPOINT}"',
             f"observation_keys = {json.dumps(list(OBSERVATION_KEYS))}", ""]
    for warden_name, lerobot_name in CAMERAS:
        lines += ["[[cameras]]", f'warden = "{warden_name}"', f'lerobot = "{lerobot_name}"',
                  f"width = {SIDE}", f"height = {SIDE}", ""]
    return "\n".join(lines)


def started(command: list[str], log: Path) -> tuple[subprocess.Popen[str], int]:
    """A child that prints ``READY {"port": N}``; its stderr goes to ``log``."""
    child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=log.open("w"), text=True,
                             cwd=ROOT)
    assert child.stdout is not None
    line = child.stdout.readline()
    if not line.startswith("READY "):
        child.kill()
        raise RuntimeError(f"{command[1]} did not start: {line!r}\n{log.read_text()}")
    return child, json.loads(line[6:])["port"]


@contextlib.contextmanager
def stand_in(replies: Path, workdir: Path) -> Iterator[tuple[int, Path]]:
    record = workdir / "standin.jsonl"
    child, port = started([str(sidecar_python()), str(HERE / "standin_server.py"),
                           "--replies", str(replies), "--record", str(record)],
                          workdir / "standin.log")
    try:
        yield port, record
    finally:
        child.terminate()
        child.wait(timeout=10)


@contextlib.contextmanager
def sidecar(config_text: str, workdir: Path) -> Iterator[tuple[int, dict[str, Any], Path]]:
    config = workdir / "sidecar.toml"
    config.write_text(config_text)
    log = workdir / "sidecar.log"
    child = subprocess.Popen([str(sidecar_python()), "-m", "sidecars.lerobot", str(config)],
                             stdout=subprocess.PIPE, stderr=log.open("w"), text=True, cwd=ROOT)
    assert child.stdout is not None
    line = child.stdout.readline()
    if not line.startswith("READY "):
        child.kill()
        raise RuntimeError(f"the sidecar did not start: {line!r}\n{log.read_text()}")
    ready = json.loads(line[6:])
    try:
        yield ready["port"], ready, log
    finally:
        child.terminate()
        child.wait(timeout=10)


def records(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def hello() -> ClientHello:
    return ClientHello(
        skill="peg_insert", skill_version="1.0.0", observation_keys=OBSERVATION_KEYS,
        action_dim=len(JOINTS), action_units="rad", action_frame="joint",
        controller_mode="joint_position", control_rate_hz=500.0, calibration_epoch="cal-1",
        queue_epoch=0, protocol=(1, 3), reason_codes=tuple(code.value for code in ReasonCode))


@dataclass
class Robot:
    """warden's side of one session, by hand: hello, the core's decision, observations."""

    ws: ClientConnection
    allowlist: frozenset[tuple[str, str]]

    async def handshake(self) -> wire.Offer:
        own = hello()
        await self.ws.send(wire.encode(wire.Hello(client_id="robot-test", protocol=(1, 3),
                                                  hello=own)))
        offer = await self.next_of(wire.Offer)
        decision, _ = evaluate(own, msgspec.to_builtins(offer.offer), self.allowlist)
        await self.ws.send(wire.encode(wire.Decision(decision=decision, queue_epoch=0)))
        if decision.decision is not HandshakeVerdict.ACCEPT:
            raise AssertionError(f"the robot side rejected the offer: {decision.reasons}")
        return offer

    async def observe(self, index: int, t_state: int, q: tuple[float, ...],
                      encoding: wire.ImageEncoding = wire.ImageEncoding.RAW) -> None:
        images = []
        rng = np.random.default_rng(index)
        for name, _ in CAMERAS:
            rgb = rng.integers(0, 256, (SIDE, SIDE, 3), np.uint8)
            raw = encoding is wire.ImageEncoding.RAW
            data = rgb.tobytes() if raw else cv2.imencode(".jpg", rgb)[1].tobytes()
            images.append(wire.image_payload(name, encoding, rgb, data, t_state,
                                             frame_digest(rgb), "cal-1"))
        await self.ws.send(wire.encode(wire.Observation(
            observation_id=f"o{index}", t_event=t_state, queue_epoch=0,
            task_phase="FREE_SPACE", q=wire.vector_payload(np.array(q)),
            images=tuple(images), t_state=t_state)))

    async def next_chunk(self, timeout_s: float = 10.0) -> Chunk:
        deadline = time.monotonic() + timeout_s
        while True:
            data = await self._recv(deadline)
            frame = wire.decode_frame(data)
            if frame.type == wire.MessageType.CHUNK:
                chunk = decode_wire_chunk(bytes(frame.body), time.monotonic_ns())
                if isinstance(chunk, MalformedChunk):
                    raise AssertionError(f"a malformed chunk: {chunk}")
                return chunk

    async def next_of(self, kind: type[Any], timeout_s: float = 10.0) -> Any:
        deadline = time.monotonic() + timeout_s
        while True:
            frame = wire.decode_frame(await self._recv(deadline))
            message = wire.decode_body(frame, wire.message_type(frame))
            if isinstance(message, kind):
                return message

    async def _recv(self, deadline: float) -> bytes:
        async with asyncio.timeout(max(0.0, deadline - time.monotonic())):
            data = await self.ws.recv()
        assert isinstance(data, bytes)
        return data


@contextlib.asynccontextmanager
async def robot(port: int, identity: dict[str, Any],  # type: ignore[no-untyped-def]
                token: str | None = None, tls: ssl.SSLContext | None = None):
    allowlist = frozenset({(identity["policy_checkpoint"], identity["config_hash"])})
    headers = {} if token is None else {"Authorization": f"Bearer {token}"}
    scheme = "ws" if tls is None else "wss"
    async with connect(f"{scheme}://127.0.0.1:{port}", subprotocols=["warden.v1"],  # type: ignore[list-item]
                       max_size=4 << 20, additional_headers=headers, ssl=tls) as ws:
        beating = asyncio.create_task(_heartbeats(ws))
        try:
            yield Robot(ws, allowlist)
        finally:
            beating.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await beating


async def _heartbeats(ws: ClientConnection) -> None:
    """warden's heartbeat, every 100 ms (the sidecar ends a session silent for a second)."""
    seq = 0
    with contextlib.suppress(ConnectionClosed):
        while True:
            seq += 1
            await ws.send(wire.encode(wire.Heartbeat(seq=seq, t_send=time.monotonic_ns())))
            await asyncio.sleep(0.1)

