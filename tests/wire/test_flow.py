"""Chunks flow over a real websocket and are admitted by the real core; the client survives
servers that are absent, and bugs are not swallowed."""

from __future__ import annotations

import asyncio
import socket

import pytest

from kernel.core.events import ChunkEvent, ObservationEvent
from kernel.shell.client import RobotClient
from kernel.shell.link_types import RobotSample
from stubs.policy_server import PolicyServer
from stubs.process import EmulatorProcess
from tests.wire.harness import LoopbackGateway, client_config, running, server_config, wait_for


async def test_chunks_flow_and_are_admitted() -> None:
    async with running() as link:
        await wait_for(lambda: len(link.gateway.admitted()) >= 5, "five admitted chunks")
        counters = link.client.counters.snapshot()
        observations = link.server.stats.observations
    gateway = link.gateway
    assert counters["chunks_admitted"] >= 5 and counters["malformed"] == 0
    # (one observation may still be in flight when the counters are read)
    assert counters["observations_sent"] - 1 <= observations <= counters["observations_sent"]
    assert counters["frames_in"] > counters["chunks_in"] and counters["bytes_out"] > 0
    # every chunk answers an observation the core recorded before the chunk arrived
    observed = {e.observation_id: e.t for e in gateway.events if isinstance(e, ObservationEvent)}
    chunks = [e.chunk for e in gateway.events if isinstance(e, ChunkEvent)]
    assert all(observed[c.observation_id] < c.client_receive for c in chunks)
    assert all(c.clock_domain == "server" for c in chunks)
    # a clean stop says bye
    assert link.server.stats.byes_received[-1:] == ["shutdown"]


async def test_against_the_server_in_a_subprocess() -> None:
    args = ("--host", "127.0.0.1", "--port", "0", "--latency-median-ms", "2",
            "--latency-p95-ms", "4", "--clock-offset-ms", "-777.5", "--heartbeat-interval", "0.05")
    process = await asyncio.to_thread(EmulatorProcess("stubs.policy_server", *args).start)
    try:
        gateway = LoopbackGateway()
        client = RobotClient(client_config(process.info["port"]), gateway)
        gateway.client = client
        stop = asyncio.Event()
        async with asyncio.TaskGroup() as tasks:
            tasks.create_task(client.run())
            tasks.create_task(gateway.run_ticks(stop))
            try:
                await wait_for(lambda: len(gateway.admitted()) >= 5, "five admitted chunks")
            finally:
                stop.set()
                client.stop()
    finally:
        await asyncio.to_thread(process.stop)
    assert gateway.handshakes()[0].decision == "ACCEPT"
    assert client.clock is not None
    true_offset = 777_500_000 - gateway.origin_ns  # both processes read the same monotonic clock
    assert abs(client.clock.offset - true_offset) <= client.clock.round_trip // 2 + 1


async def test_server_absent_at_first_is_retried_with_backoff() -> None:
    with socket.socket() as probe:  # a port nobody listens on, yet
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    gateway = LoopbackGateway()
    client = RobotClient(client_config(port), gateway)
    gateway.client = client
    stop = asyncio.Event()
    async with asyncio.TaskGroup() as tasks:
        tasks.create_task(client.run())
        tasks.create_task(gateway.run_ticks(stop))
        try:
            await wait_for(lambda: client.counters.connect_failures >= 3, "three failed attempts")
            assert len(gateway.link_events("down")) == 1  # reported once, not per attempt
            async with PolicyServer(server_config(port=port)):
                await wait_for(lambda: gateway.admitted(), "a chunk once the server is up")
        finally:
            stop.set()
            client.stop()
    assert client.counters.handshakes_accepted == 1


class _BrokenGateway(LoopbackGateway):
    def capture_observation(self, prefix_grid_ns: int | None = None,
                            at_ns: int | None = None) -> RobotSample:
        raise RuntimeError("the robot state is unreadable")


async def test_a_bug_propagates_to_the_supervisor() -> None:
    async with PolicyServer(server_config()) as server:
        gateway = _BrokenGateway()
        client = RobotClient(client_config(server.port), gateway)
        gateway.client = client
        stop = asyncio.Event()
        with pytest.RaisesGroup(RuntimeError, flatten_subgroups=True):
            async with asyncio.TaskGroup() as tasks:
                tasks.create_task(client.run())
                tasks.create_task(gateway.run_ticks(stop))
    assert client.counters.handshakes_accepted == 1
