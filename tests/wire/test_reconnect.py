"""Link loss: LinkEvent(down), reconnection, a new handshake with the new epoch, and old chunks
resent by the server refused for their epoch."""

from __future__ import annotations

import asyncio
import dataclasses
import os
import signal

from assurance.reasons import ReasonCode as R
from kernel.core.events import ChunkEvent, HandshakeEvent, LinkEvent
from kernel.core.lines import TransitionLine
from kernel.shell.client import RobotClient
from stubs.policy_server import FaultConfig
from stubs.process import EmulatorProcess
from tests.wire.harness import LoopbackGateway, client_config, running, server_config, wait_for


async def test_server_disconnect_reconnects_with_a_new_epoch() -> None:
    faults = FaultConfig(close_after=3, resend_on_reconnect=2)
    async with running(server_config(faults=faults)) as link:
        gateway, stats = link.gateway, link.server.stats
        await wait_for(lambda: len(stats.hellos) >= 2, "a second hello")
        await wait_for(lambda: len(gateway.refused_with(R.OLD_QUEUE_EPOCH)) >= 2,
                       "the resent chunks refused")
        await wait_for(lambda: len(gateway.admitted()) >= 6, "chunks in the new epoch")
        events = list(gateway.events)
    first, second = stats.hellos[0].hello.queue_epoch, stats.hellos[1].hello.queue_epoch
    assert stats.byes_sent[0] == "fault_injected"
    # the link loss was fed to the core before the new handshake
    down = next(i for i, e in enumerate(events) if isinstance(e, LinkEvent) and e.status == "down")
    handshakes = [i for i, e in enumerate(events) if isinstance(e, HandshakeEvent)]
    assert handshakes[0] < down < handshakes[1]
    # the new hello carries the epoch the core started at the link loss
    accepted_epochs = {line.queue_epoch for line in gateway.admitted()}
    assert second > first and second == gateway.handshakes()[1].queue_epoch
    assert max(accepted_epochs) == second
    resent = gateway.refused_with(R.OLD_QUEUE_EPOCH)
    assert all(line.decision in ("ignored", "rejected") for line in resent)
    first_session = {line.chunk_id for line in gateway.chunk_lines() if line.queue_epoch < second}
    assert {line.chunk_id for line in resent} <= first_session
    assert stats.chunks_resent == 2 and link.client.counters.reconnects == 1


async def test_resent_chunk_never_seen_is_refused_for_its_epoch_too() -> None:
    # Every second chunk of the first session is dropped, so a resend replays one the client
    # never saw: not a duplicate, still refused for its epoch (and its forgotten observation).
    faults = FaultConfig(drop=0.5, close_after=2, resend_on_reconnect=2)
    async with running(server_config(faults=faults)) as link:
        await wait_for(lambda: link.server.stats.chunks_resent >= 2, "a resend")
        await wait_for(lambda: len(link.gateway.refused_with(R.OLD_QUEUE_EPOCH)) >= 2,
                       "their refusals")
    lines = link.gateway.refused_with(R.OLD_QUEUE_EPOCH)
    unseen = [line for line in lines if R.DUPLICATE not in line.reasons]
    seen = [line for line in lines if R.DUPLICATE in line.reasons]
    assert unseen and all(line.decision == "rejected" for line in unseen)
    assert all(R.UNKNOWN_OBSERVATION in line.reasons for line in unseen)
    assert seen and all(line.decision == "ignored" for line in seen)


async def test_server_gone_then_back_the_client_keeps_trying() -> None:
    faults = FaultConfig(close_after=1, affect_connections=3)
    async with running(server_config(faults=faults)) as link:
        await wait_for(lambda: link.client.counters.handshakes_accepted >= 4, "four sessions")
    downs = link.gateway.link_events("down")
    assert len(downs) >= 3
    assert link.client.counters.reconnects >= 3


async def test_a_silent_server_is_a_lost_link_within_the_heartbeat_timeout() -> None:
    # docs/protocol.md: the core learns of a silent peer heartbeat_timeout_s after its last
    # frame (plus the loop's latency), before any goodbye or close handshake with it.
    timeout_s = 0.15
    async with running(server_config(faults=FaultConfig(stall_after=2)),
                       heartbeat_timeout_ms=timeout_s * 1000) as link:
        await wait_for(lambda: link.gateway.link_events("down"), "the link declared lost")
        events = list(link.gateway.events)
        transitions = [line for line in link.gateway.lines
                       if isinstance(line, TransitionLine) and line.machine == "fallback"]
    down = next(i for i, e in enumerate(events) if isinstance(e, LinkEvent) and e.status == "down")
    last_chunk = next(e for e in reversed(events[:down]) if isinstance(e, ChunkEvent))
    silent_s = (events[down].t - last_chunk.t) * 1e-9
    assert timeout_s - 0.01 <= silent_s <= timeout_s + 0.1
    assert link.client.counters.link_timeouts == 1
    # so the starved queue never escalated first: DEGRADED, which a new handshake recovers
    assert (transitions[0].to, transitions[0].trigger) == ("DEGRADED", R.LINK_LOST)


class _LaunchedServer:
    """A reference server in a subprocess that this test 'launched': the client may restart it
    (as kernel/app/live.py restarts the one a run launched)."""

    ARGS = ("--host", "127.0.0.1", "--port", "0", "--latency-median-ms", "2",
            "--latency-p95-ms", "4", "--heartbeat-interval", "0.05", "--max-speed", "0.1")

    def __init__(self) -> None:
        self.process: EmulatorProcess | None = None
        self.pids: list[int] = []

    def start(self) -> str:
        self.process = EmulatorProcess("stubs.policy_server", *self.ARGS).start()
        self.pids.append(self.process.pid)
        return f"ws://127.0.0.1:{self.process.info['port']}"

    def stop(self) -> None:
        if self.process is not None:
            self.process.stop()

    async def restart(self) -> str:
        await asyncio.to_thread(self.stop)
        return await asyncio.to_thread(self.start)


async def test_a_launched_server_that_hangs_is_restarted_and_the_session_resumes() -> None:
    server = _LaunchedServer()
    url = await asyncio.to_thread(server.start)
    gateway = LoopbackGateway()
    client = RobotClient(dataclasses.replace(client_config(0, heartbeat_timeout_ms=150.0),
                                             url=url), gateway, server=server)
    gateway.client = client
    stop = asyncio.Event()
    try:
        async with asyncio.TaskGroup() as tasks:
            tasks.create_task(client.run())
            tasks.create_task(gateway.run_ticks(stop))
            try:
                await wait_for(lambda: len(gateway.admitted()) >= 3, "a working session")
                os.kill(server.pids[0], signal.SIGSTOP)  # hung, not dead: only silence tells
                await wait_for(lambda: client.counters.server_restarts >= 1, "a restart", 20.0)
                await wait_for(lambda: client.counters.handshakes_accepted >= 2, "a new session")
                admitted = len(gateway.admitted())
                await wait_for(lambda: len(gateway.admitted()) > admitted, "chunks again")
            finally:
                stop.set()
                client.stop()
    finally:
        await asyncio.to_thread(server.stop)
    assert len(server.pids) == 2 and client.counters.link_timeouts >= 1
    assert len(gateway.link_events("down")) >= 1
