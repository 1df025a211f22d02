"""Hostile peers: numbers out of any plausible range never raise out of the link task, and
nothing the core is fed stops a journal from replaying."""

from __future__ import annotations

import time

import numpy as np
import pytest

from assurance.envelope import decode_wire_chunk
from assurance.reasons import ReasonCode as R
from kernel.config.build import build_config
from kernel.core.effects import Step
from kernel.core.events import ChunkEvent, ClockSyncEvent, ObservationEvent, TickEvent
from kernel.core.lines import ChunkLine, encode
from kernel.core.runtime import Core
from kernel.scenario.fields import Where
from kernel.shell.link_budget import AdmissionPacer, TokenBucket
from kernel.shell.link_intake import OTHERS_QUEUED
from kernel.shell.link_settings import PolicySettings
from kernel.shell.link_types import ClientConfig
from kernel.wire import MAX_CLOCK_OFFSET_NS
from peer import envelope as peer_env
from peer import protocol as peer
from stubs.policy_server import FaultConfig
from tests.wire.harness import (
    LoopbackGateway,
    journal_round_trip,
    running,
    server_config,
    wait_for,
)
from tools.scenarios.base import ScenarioSpec


@pytest.mark.parametrize("t_server", [2**64 - 1, -(2**63 - 1), 2**63 - 1],
                         ids=["beyond_int64", "int64_min", "int64_max"])
async def test_an_implausible_clock_pong_is_a_violation_never_a_crash(t_server: int) -> None:
    faults = FaultConfig(clock_t_server=t_server)
    async with running(server_config(faults=faults)) as link:
        counters = link.client.counters
        await wait_for(lambda: counters.protocol_violations >= 1, "a protocol violation")
        await wait_for(lambda: len(link.gateway.admitted()) >= 2, "a sane second session")
    assert counters.protocol_violations == 1  # the first connection only
    assert "protocol_violation" in link.server.stats.byes_received
    syncs = [e for e in link.gateway.events if isinstance(e, ClockSyncEvent)]
    assert syncs and all(abs(sync.offset) <= MAX_CLOCK_OFFSET_NS for sync in syncs)
    journal_round_trip(link.gateway)


def _chunk_events(gateway: LoopbackGateway) -> list[ChunkEvent]:
    return [e for e in gateway.events if isinstance(e, ChunkEvent)]


async def test_a_chunk_flood_reaches_the_core_at_the_chunk_rate_and_answers_nothing() -> None:
    rate = 40.0
    faults = FaultConfig(flood_chunks_per_s=2000.0)
    async with running(server_config(faults=faults), max_chunks_per_s=rate,
                       max_frames_per_s=50_000.0) as link:
        counters = link.client.counters
        await wait_for(lambda: counters.chunks_dropped >= 200, "flood chunks dropped")
        await wait_for(lambda: len(link.gateway.admitted()) >= 4, "answers admitted meanwhile")
        fed = _chunk_events(link.gateway)
        refused = link.gateway.refused_with(R.OBSERVATION_ANSWERED)
        admitted = link.gateway.admitted()
        seen = counters.snapshot()
    assert counters.connects == 1, "the flood does not cost the session"
    # What the bucket lets through beside the expected answers: one burst, then the rate.
    span_s = (fed[-1].t - fed[0].t) * 1e-9
    bucket = TokenBucket(rate)
    assert len(fed) - len(admitted) <= bucket.burst + rate * span_s + 1
    assert refused, "the repeated answers are refused as answering nothing pending"
    assert all(line.reasons == (R.OBSERVATION_ANSWERED,) for line in refused)
    queued = seen["chunks_in"] - len(fed) - seen["chunks_dropped"]
    assert 0 <= queued <= OTHERS_QUEUED + link.client.config.policy.max_requests_in_flight


async def test_frames_over_the_frame_rate_are_dropped_undecoded() -> None:
    rate = 300.0
    faults = FaultConfig(flood_chunks_per_s=3000.0)
    async with running(server_config(faults=faults), max_frames_per_s=rate) as link:
        counters = link.client.counters
        await wait_for(lambda: counters.chunks_in > 0, "a first chunk")
        start_s, decoded_before = time.monotonic(), counters.frames_in - counters.frames_dropped
        await wait_for(lambda: counters.frames_dropped >= 500, "frames dropped")
        span_s = time.monotonic() - start_s
        decoded = counters.frames_in - counters.frames_dropped - decoded_before
    assert decoded <= TokenBucket(rate).burst + rate * span_s + 1


@pytest.mark.parametrize(("faults", "changes", "counter"), [
    (FaultConfig(big_chunk_rows=2000), {}, "oversized"),  # a 96 kB chunk: over 64 KiB
    (FaultConfig(junk_frame_bytes=1_000_000), {}, "oversized"),
    (FaultConfig(junk_frame_bytes=4_000), {}, "protocol_violations"),
    (FaultConfig(big_chunk_rows=200), {"max_frame_bytes": 4096}, "oversized"),
], ids=["big_chunk", "junk_1MB", "junk_4kB", "configured_limit"])
async def test_an_oversized_or_junk_frame_ends_the_connection_unread(
    faults: FaultConfig, changes: dict[str, int], counter: str
) -> None:
    async with running(server_config(faults=faults), **changes) as link:
        counters = link.client.counters
        await wait_for(lambda: getattr(counters, counter) >= 1, counter)
        await wait_for(lambda: len(link.gateway.admitted()) >= 2, "a sane second session")
    assert all(len(event.frame or b"") < 4096 for event in _chunk_events(link.gateway))
    journal_round_trip(link.gateway)


async def test_requests_in_flight_are_bounded_when_nothing_answers() -> None:
    limit = 3
    async with running(server_config(faults=FaultConfig(drop=1.0)),
                       max_requests_in_flight=limit, request_timeout_ms=150.0) as link:
        counters = link.client.counters
        await wait_for(lambda: counters.requests_expired >= 2 * limit, "expired requests")
        sent, expired = counters.observations_sent, counters.requests_expired
    assert counters.requests_waited >= 1
    assert sent <= limit + expired + 1  # +1: the request on its way out as we looked


async def test_admissions_run_at_most_the_paced_number_per_control_period() -> None:
    pacer = AdmissionPacer(per_period=1, reserve_ns=1_000_000)
    faults = FaultConfig(flood_chunks_per_s=2000.0)
    async with running(server_config(faults=faults), pacer=pacer,
                       max_frames_per_s=50_000.0, max_chunks_per_s=1000.0) as link:
        await wait_for(lambda: len(_chunk_events(link.gateway)) >= 100, "many admissions")
        await wait_for(lambda: len(link.gateway.admitted()) >= 3, "answers admitted")
        events = list(link.gateway.events)
    per_period, most = 0, 0
    for event in events:
        if isinstance(event, TickEvent):
            per_period = 0
        elif isinstance(event, ChunkEvent):
            per_period += 1
            most = max(most, per_period)
    assert most == 1
    assert link.client.counters.admissions_deferred > 0


EXTREMES = [-(2**63 - 1), -(2**62), -1, 0, 2**62, 2**63 - 1]


@pytest.mark.parametrize("offset", [-MAX_CLOCK_OFFSET_NS, 0, MAX_CLOCK_OFFSET_NS])
@pytest.mark.parametrize("time", EXTREMES)
def test_times_at_the_ends_of_their_range_are_refused_never_raised(offset: int,
                                                                   time: int) -> None:
    """Any time a chunk may carry, under any offset a sync may measure: a decision line that
    encodes, never an exception out of the core."""
    spec = ScenarioSpec(name="s", description="", events=[], until=0, expect=[],
                        phase="FREE_SPACE")
    core = Core(build_config(spec.document(), Where("s", "")))
    core.step(ClockSyncEvent(t=1, domain="server", offset=offset, round_trip=2**63 - 1))
    core.step(ObservationEvent(t=2, observation_id="o1"))
    chunk = peer_env.ChunkEnvelope(
        chunk_id="c1", sequence=2**63 - 1, queue_epoch=0, policy_checkpoint="act-insert-2026-07",
        config_hash="cfg-9f2c", skill_version="3.1.0", task_phase="FREE_SPACE",
        controller_mode="joint_position", calibration_epoch="cal-12", observation_id="o1",
        first_action_time=time, action_dt=2**63 - 1, actions=peer.array_payload(np.zeros((3, 6))),
        observation_event_time=time, observation_arrival_time=time, inference_start=time,
        inference_end=time, server_send=time, max_observation_age=time, max_action_age=time,
        clock_domain="server")
    body = peer_env.encode_chunk_body(chunk)
    step = core.step(ChunkEvent(3, decode_wire_chunk(body, 3), body))
    step = Step(step.lines + core.step(TickEvent(t=4)).lines, ())
    (line,) = [x for x in step.lines if isinstance(x, ChunkLine)]
    assert line.decision == "rejected" and R.HANDSHAKE_REQUIRED not in line.reasons
    assert all(encode(x) for x in step.lines)


def test_the_manifests_link_limits_reach_the_client() -> None:
    settings = PolicySettings(max_frame_bytes=4096, max_frames_per_s=50.0, max_chunks_per_s=7.0,
                              max_requests_in_flight=2, request_timeout_ms=80.0,
                              heartbeat_interval_ms=50.0, heartbeat_timeout_ms=200.0)
    config = ClientConfig(url="ws://127.0.0.1:1", policy=settings).policy
    assert (config.max_frame_bytes, config.max_frames_per_s, config.max_chunks_per_s) == (
        4096, 50.0, 7.0)
    assert (config.max_requests_in_flight, config.request_timeout_s) == (2, 0.08)
    assert (config.heartbeat_interval_s, config.heartbeat_timeout_s) == (0.05, 0.2)
    assert ClientConfig(url="ws://127.0.0.1:1").policy == PolicySettings()
