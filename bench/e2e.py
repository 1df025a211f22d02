"""End-to-end link latency over loopback: observation captured → chunk admitted by the core.

The reference policy server runs in a subprocess with zero simulated inference time, so the
figure is what the link itself costs: capture and encode the observation, loopback websocket
both ways, the server's policy step, chunk encode, frame and envelope decode, clock-domain
translation and the core's full admission (every gate, merge, projection, log line). The robot
side is the real :class:`kernel.shell.client.RobotClient` feeding a real core; the next
observation is requested as soon as a chunk is admitted.

A naive baseline runs in the same process and the same run: the same observation → chunk
exchange over a websocket with stdlib-json text frames (actions as nested lists, no envelope,
no clock sync, no heartbeats), admitted by the same core. Figures are printed, never asserted
(the machine is shared and noisy); compare the ratio within one run. Target: p99 <= 2 ms.

    .venv/bin/python bench/e2e.py [--samples 2000] [--horizon 20]
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import gc
import json
import os
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # run as a script: make the repository importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import msgspec
import numpy as np
import uvloop
from websockets.asyncio.client import connect
from websockets.asyncio.server import serve

from assurance.envelope import ArrayPayload, MalformedChunk, WireChunk, from_wire
from assurance.handshake import ClientHello
from kernel.config.build import build_config
from kernel.core.effects import Setpoint, Step
from kernel.core.events import (
    ChunkEvent,
    Event,
    HandshakeEvent,
    ObservationEvent,
    StateEvent,
    TickEvent,
)
from kernel.core.lines import ChunkLine, Line
from kernel.core.runtime import Core
from kernel.scenario.fields import Where
from kernel.shell.client import RobotClient
from kernel.shell.link_settings import PolicySettings
from kernel.shell.link_types import ClientConfig, RobotSample
from kernel.summary import ADMITTED
from stubs.policy_server import ServerConfig
from stubs.process import EmulatorProcess
from tools.scenarios.base import ScenarioSpec, offer

ROOT = Path(__file__).resolve().parents[1]
WARMUP = 100


def _core() -> Core:
    spec = ScenarioSpec(name="e2e", description="", events=[], until=0, expect=[],
                        phase="FREE_SPACE")
    config = build_config(spec.document(), Where("e2e", ""))
    return Core(dataclasses.replace(config, initial_session=None))


def _percentiles(samples: list[int]) -> tuple[float, float]:
    ordered = sorted(samples[WARMUP:])
    return ordered[len(ordered) // 2] / 1e3, ordered[int(len(ordered) * 0.99)] / 1e3


class _BenchGateway:
    """The shell side: a real core; each admitted chunk records its latency and asks for more."""

    def __init__(self, samples: int) -> None:
        self.core = _core()
        self.q = self.core.config.initial_q.copy()
        """Where the arm is: it follows every setpoint exactly (:meth:`run_ticks`)."""
        self.wanted = samples
        self.latencies: list[int] = []
        self.legs: list[tuple[int, int, int, int]] = []
        self.done = asyncio.Event()
        self.client: RobotClient | None = None
        self._observed: dict[str, int] = {}

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def feed(self, event: Event) -> Step:
        if isinstance(event, ObservationEvent):
            self._observed[event.observation_id] = event.t
        step = self.core.step(event)
        lines = step.lines
        if isinstance(event, ChunkEvent) and _admitted(lines):
            t_obs = self._observed.pop(event.chunk.observation_id)  # type: ignore[union-attr]
            self.latencies.append(time.monotonic_ns() - t_obs)
            self._record_legs(event, t_obs)
            self._next()
        elif any(isinstance(line, ChunkLine) for line in lines):
            raise RuntimeError(f"benchmark chunk refused: {lines}")
        return step

    def on(self, kind: type, handler: Callable[[Any], None]) -> None:
        """The client registers for requests and session ends; this bench asks for every
        observation itself (one at a time, after each admission)."""

    def client_side_hello(self) -> ClientHello:
        return self.core.config.client.hello(self.core.status().epoch)

    def capture_observation(self, prefix_grid_ns: int | None = None,
                            at_ns: int | None = None) -> RobotSample:
        return RobotSample(q=self.q.copy(), task_phase="FREE_SPACE",
                           qd=np.zeros(6), wrench=np.zeros(6))

    async def run_ticks(self, period_s: float = 0.002) -> None:
        """The control loop, as the shell runs it: ticks consume the queue; the arm follows."""
        while not self.done.is_set():
            motion = self.core.step(TickEvent(t=self.now_ns())).motion
            if isinstance(motion, Setpoint):
                self.core.step(StateEvent(t=self.now_ns(), q=motion.q))
                self.q = np.array(motion.q)
            await asyncio.sleep(period_s)

    def _record_legs(self, event: ChunkEvent, t_obs: int) -> None:
        """Where the time went, from the envelope's server times and the measured offset."""
        clock = self.client.clock if self.client is not None else None
        chunk = event.chunk
        if clock is None or isinstance(chunk, MalformedChunk):
            return
        arrival = chunk.times["observation_arrival_time"] or 0
        sent = chunk.times["server_send"] or 0
        self.legs.append((arrival + clock.offset - t_obs, sent - arrival,
                          event.t - (sent + clock.offset), time.monotonic_ns() - event.t))

    def _next(self) -> None:
        if len(self.latencies) >= self.wanted:
            self.done.set()
        elif self.client is not None:
            self.client.request()


def _admitted(lines: tuple[Line, ...]) -> bool:
    return any(isinstance(line, ChunkLine) and line.decision in ADMITTED for line in lines)


async def _run_msgpack(port: int, samples: int) -> _BenchGateway:
    gateway = _BenchGateway(samples)
    # One observation after another as fast as the link answers (a few thousand frames a
    # second): above the default frame-rate limit, which guards a robot against a flooding
    # server; a dropped answer would stall this closed loop, which never asks again.
    link = PolicySettings(heartbeat_interval_ms=500.0, heartbeat_timeout_ms=5000.0,
                          max_frames_per_s=100_000.0)
    client = RobotClient(ClientConfig(url=f"ws://127.0.0.1:{port}", client_id="bench",
                                      policy=link), gateway)
    gateway.client = client
    async with asyncio.TaskGroup() as tasks:
        tasks.create_task(client.run())
        tasks.create_task(gateway.run_ticks())
        while client.fingerprint is None:  # wait for the handshake
            await asyncio.sleep(0.01)
        client.request()
        await gateway.done.wait()
        client.stop()
    return gateway


# -- the naive baseline ---------------------------------------------------------------------


async def _run_json(port: int, samples: int, horizon: int) -> list[int]:
    gateway = _BenchGateway(samples)
    gateway.feed(HandshakeEvent(t=gateway.now_ns(), offer=offer(chunk_horizon=horizon)))
    async with asyncio.TaskGroup() as tasks:
        tasks.create_task(gateway.run_ticks())
        async with connect(f"ws://127.0.0.1:{port}", compression=None, proxy=None) as ws:
            for index in range(samples):
                await ws.send(json.dumps(_json_observation(gateway, f"json/{index}")))
                doc = json.loads(await ws.recv())
                t_receive = gateway.now_ns()
                doc["actions"] = ArrayPayload.from_array(np.asarray(doc["actions"], dtype=float))
                gateway.feed(ChunkEvent(t_receive, from_wire(msgspec.convert(doc, WireChunk),
                                                             t_receive)))
    return gateway.latencies


def _json_observation(gateway: _BenchGateway, observation_id: str) -> dict:
    t_obs = gateway.now_ns()
    gateway.feed(ObservationEvent(t=t_obs, observation_id=observation_id))
    return {"observation_id": observation_id, "t_event": t_obs,
            "queue_epoch": gateway.core.status().epoch, "task_phase": "FREE_SPACE",
            "q": gateway.q.tolist(), "qd": [0.0] * 6,
            "wrench": [0.0] * 6}


async def _json_server(horizon: int) -> None:
    config = ServerConfig(lead_ms=5.0, horizon=horizon)
    policy, rng = config.policy(), np.random.default_rng(0)
    sequence = iter(range(1, 1 << 62))

    async def answer(ws) -> None:  # type: ignore[no-untyped-def]
        async for text in ws:
            observation = json.loads(text)
            start = time.monotonic_ns()
            q = np.asarray(observation["q"], dtype=float)
            actions = policy.actions(q, config.lead_ns / 1e9, rng)
            await ws.send(json.dumps(_json_chunk(config, observation, actions, start,
                                                 next(sequence))))

    stop = asyncio.Event()
    asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, stop.set)
    async with serve(answer, "127.0.0.1", 0, compression=None) as server:
        port = next(iter(server.sockets)).getsockname()[1]
        print(f"READY {json.dumps({'port': port})}", flush=True)
        await stop.wait()


def _json_chunk(config: ServerConfig, observation: dict, actions: np.ndarray, start: int,
                sequence: int) -> dict:
    t_obs = observation["t_event"]
    now = time.monotonic_ns()
    return {
        "chunk_id": f"json-{sequence}", "sequence": sequence,
        "queue_epoch": observation["queue_epoch"], "policy_checkpoint": config.policy_checkpoint,
        "config_hash": config.config_hash, "skill": config.skill,
        "skill_version": config.skill_version, "task_phase": observation["task_phase"],
        "controller_mode": config.controller_mode, "calibration_epoch": config.calibration_epoch,
        "observation_id": observation["observation_id"], "observation_event_time": t_obs,
        "clock_domain": "client", "inference_start": start, "inference_end": now,
        "server_send": now, "first_action_time": t_obs + config.lead_ns,
        "action_dt": round(config.action_dt_ms * 1e6), "actions": actions.tolist(),
        "max_observation_age": 80_000_000, "max_action_age": 200_000_000,
        "state_fingerprint": {"q": observation["q"], "hash": ""},
        "replacement_policy": "replace", "action_units": "rad", "action_frame": "joint",
    }


# -- main -------------------------------------------------------------------------------------


def _start(module_args: tuple[str, ...]) -> EmulatorProcess:
    os.environ["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
    return EmulatorProcess(*module_args)  # started by ``with``


async def _measure(samples: int, horizon: int) -> None:
    gc.collect()
    gc.freeze()  # what a real-time shell does after start-up: no long gen-2 pauses
    server_args = ("--port", "0", "--latency-median-ms", "0", "--latency-p95-ms", "0",
                   "--lead-ms", "5", "--heartbeat-interval", "0.5", "--horizon", str(horizon))
    with _start(("stubs.policy_server", *server_args)) as server:
        warden = await _run_msgpack(server.info["port"], samples)
    wire = _percentiles(warden.latencies)
    legs = np.median(np.array(warden.legs[WARMUP:]), axis=0) / 1e3
    with _start(("bench.e2e", "--json-server", "--horizon", str(horizon))) as server:
        naive = _percentiles(await _run_json(server.info["port"], samples, horizon))
    print(f"observation -> admitted over loopback, {horizon}x6 chunks, {samples} samples "
          f"({WARMUP} warm-up dropped)")
    print(f"  warden wire (msgpack, raw arrays)  p50 {wire[0]:8.1f} us   p99 {wire[1]:8.1f} us"
          f"   target p99 <= 2000 us: {'met' if wire[1] <= 2000 else 'MISSED'}")
    print(f"    legs, p50 us: observation out {legs[0]:.0f}, server {legs[1]:.0f}, "
          f"chunk back {legs[2]:.0f}, decode + admission {legs[3]:.0f}")
    print(f"  naive baseline (stdlib json)       p50 {naive[0]:8.1f} us   p99 {naive[1]:8.1f} us")
    print(f"  baseline / warden                  p50 {naive[0] / wire[0]:8.2f} x"
          f"     p99 {naive[1] / wire[1]:8.2f} x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--horizon", type=int, default=20, help="actions per chunk")
    parser.add_argument("--json-server", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    samples = max(args.samples, WARMUP * 2)
    uvloop.run(_json_server(args.horizon) if args.json_server
               else _measure(samples, args.horizon))


if __name__ == "__main__":
    main()
