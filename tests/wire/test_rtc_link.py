"""Real-time chunking across the network: warden's client sends the committed prefix to a
server that offered it, the reference server honours it, and the core checks it
(assurance/rtc.py). A real core, client and server over loopback (tests/wire/harness.py)."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from assurance.envelope import Chunk
from assurance.rtc import Committed
from kernel.core.events import ChunkEvent, ObservationEvent
from kernel.shell.link_rtc import PrefixPlanner
from kernel.wire import WirePrefix, prefix_payload
from peer import protocol as peer_protocol
from stubs.policy_server.rtc import read_prefix
from tests.wire.harness import (
    LoopbackGateway,
    journal_round_trip,
    running,
    server_config,
    wait_for,
)

MS = 1_000_000


def _conditioned(events: list) -> list[Chunk]:
    return [e.chunk for e in events if isinstance(e, ChunkEvent) and isinstance(e.chunk, Chunk)
            and e.chunk.rtc_delay is not None]


@pytest.mark.parametrize("phase", ["FREE_SPACE", "PRE_CONTACT"])
async def test_a_server_that_offers_rtc_gets_the_prefix_and_its_chunks_are_admitted(
        phase: str) -> None:
    """PRE_CONTACT forbids trimming: a conditioned chunk, due from the observation's time,
    always arrives with its first actions due, and only the committed prefix may go."""
    async with running(server_config(rtc=True), LoopbackGateway(phase)) as link:
        gateway = link.gateway
        await wait_for(lambda: len(_conditioned(gateway.events)) >= 6, "six conditioned chunks")
        await wait_for(lambda: len(gateway.admitted()) >= 8, "eight admitted chunks")
        events, lines = list(gateway.events), list(gateway.chunk_lines())
    prefixes = [e.rtc for e in events if isinstance(e, ObservationEvent) and e.rtc is not None]
    assert prefixes, "no observation carried a prefix"
    for prefix in prefixes:
        assert prefix.action_dt == 20 * MS and len(prefix.actions) >= prefix.delay >= 1
        assert prefix.horizon == 20 - prefix.delay
    journal_round_trip(gateway)  # every prefix as sent is a journal line that parses back
    decided = {line.chunk_id: line for line in lines}
    conditioned = [c for c in _conditioned(events) if c.chunk_id in decided]
    admitted = [c for c in conditioned if decided[c.chunk_id].decision != "rejected"]
    assert len(admitted) >= 3, [decided[c.chunk_id] for c in conditioned]
    # Due from the prefix's first action, before the observation: each arrives with actions
    # due, and (where trimming is forbidden too) drops only those.
    assert all(decided[c.chunk_id].decision == "trimmed" for c in admitted)
    # The server reproduces the prefix exactly; an answer later than the measured p95 (a
    # pause of this shared machine) may still come too late, and is refused as that alone.
    assert not [line for line in lines if "RTC_PREFIX_MISMATCH" in line.reasons]
    late = [line for line in lines if "RTC_DELAY_EXCEEDED" in line.reasons]
    assert len(late) < len(admitted)
    assert not [line for line in lines if "EXPIRED" in line.reasons and line not in late]


async def test_a_server_that_does_not_offer_it_never_sees_a_prefix() -> None:
    async with running(server_config()) as link:
        await wait_for(lambda: len(link.gateway.admitted()) >= 4, "four admitted chunks")
        events = list(link.gateway.events)
    observations = [e for e in events if isinstance(e, ObservationEvent)]
    assert observations and all(e.rtc is None for e in observations)
    assert not _conditioned(events)


def test_no_prefix_before_the_grid_and_a_round_trip_are_known() -> None:
    planner = PrefixPlanner()
    committed = Committed(0, np.ones((5, 3)))
    planner.begin(offered=True, chunk_horizon=20)
    assert planner.grid_ns() is None and planner.prefix(committed, 0) is None
    planner.answered(30 * MS, 20 * MS)
    assert planner.grid_ns() == 20 * MS
    prefix = planner.prefix(committed, 0)
    assert prefix is not None and (prefix.delay, prefix.horizon) == (2, 18)
    # The first committed action was due 15 ms before the observation: 45 ms, 3 actions.
    later = planner.prefix(committed, 15 * MS)
    assert later is not None and later.delay == 3
    assert planner.prefix(Committed(0, np.zeros((0, 3))), 0) is None  # nothing to condition on
    planner.begin(offered=False, chunk_horizon=20)  # a server that does not offer it
    planner.answered(30 * MS, 20 * MS)
    assert planner.grid_ns() is None


def test_the_delay_is_the_95th_percentile_round_trip_in_actions() -> None:
    planner = PrefixPlanner()
    planner.begin(offered=True, chunk_horizon=10)
    for round_trip_ms in [95] + [10] * 18:  # too few to tell a percentile: the longest
        planner.answered(round_trip_ms * MS, 20 * MS)
    prefix = planner.prefix(Committed(0, np.ones((8, 3))), 0)
    assert prefix is not None and prefix.delay == 5
    planner.begin(offered=True, chunk_horizon=10)
    for round_trip_ms in [10] * 19 + [95]:  # one slow answer in twenty: the 95th is 10 ms
        planner.answered(round_trip_ms * MS, 20 * MS)
    prefix = planner.prefix(Committed(0, np.ones((8, 3))), 0)
    assert prefix is not None and prefix.delay == 1
    for _ in range(2):  # two in twenty-two: now the 95th percentile is the slow one
        planner.answered(95 * MS, 20 * MS)
    prefix = planner.prefix(Committed(0, np.ones((8, 3))), 0)
    assert prefix is not None and prefix.delay == 5  # ceil(95 / 20), within the 8 committed
    short = planner.prefix(Committed(0, np.ones((3, 3))), 0)
    assert short is not None and short.delay == 3  # never more than was committed


def test_the_horizon_a_large_offer_implies_still_fits_the_wire() -> None:
    """An offer's chunk_horizon is any positive number: the horizon sent is capped at what a
    prefix may say, or every observation would be undecodable, and its journal unreadable."""
    planner = PrefixPlanner()
    planner.begin(offered=True, chunk_horizon=2000)
    planner.answered(30 * MS, 20 * MS)
    prefix = planner.prefix(Committed(0, np.ones((4, 6))), 0)
    assert prefix is not None and prefix.horizon == 1024
    body = msgspec.msgpack.encode(prefix_payload(prefix))
    assert msgspec.msgpack.decode(body, type=WirePrefix).horizon == 1024
    peer = msgspec.msgpack.decode(body, type=peer_protocol.Prefix)  # and the server reads it
    assert peer.horizon == 1024


def _peer_prefix(width: int, first: int = 0) -> peer_protocol.Prefix:
    rows = np.zeros((3, width))
    return peer_protocol.Prefix(actions=peer_protocol.ArrayPayload(
        dtype="<f8", shape=rows.shape, data=rows.tobytes()), first_action_time=first,
        action_dt=20 * MS, delay=2, horizon=5)


def test_the_reference_server_reads_a_prefix_when_it_arrives() -> None:
    """Checked with the observation, where a violation ends the connection with a bye, not in
    the inference task (a wrong width once escaped there as an exception group)."""
    config = server_config(rtc=True, action_dt_ms=20.0)
    width = len(config.goal)
    assert read_prefix(config, _peer_prefix(width), client_offset=5) is not None
    assert read_prefix(server_config(), _peer_prefix(width), client_offset=5) is None
    assert read_prefix(config, _peer_prefix(width), client_offset=None) is None
    with pytest.raises(peer_protocol.ProtocolViolation, match="rows of"):
        read_prefix(config, _peer_prefix(width + 1), client_offset=5)
    with pytest.raises(peer_protocol.ProtocolViolation, match="range"):
        read_prefix(config, _peer_prefix(width, first=-(2**63) + 1), client_offset=2**62)
