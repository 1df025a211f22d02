"""The policy link's protocol object, driven directly with bytes and times: no socket, task or
clock (kernel/shell/link_protocol.py)."""

from __future__ import annotations

import msgspec
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from assurance.envelope import Chunk, MalformedChunk
from assurance.handshake import HandshakeDecision, HandshakeOffer, HandshakeVerdict
from kernel import wire
from kernel.core.effects import ChunkDecision
from kernel.core.events import ChunkEvent, ObservationEvent
from kernel.core.lines import Decision
from kernel.shell.link_protocol import (
    ChunksWaiting,
    Ended,
    Feed,
    HelloDue,
    OfferArrived,
    Send,
    WardenProtocol,
)
from kernel.shell.link_types import LinkCounters, LinkTiming, RobotSample
from kernel.wire import ByeReason
from tests.core.test_handshake import HELLO, OFFER

OFFERED = msgspec.convert(OFFER, HandshakeOffer)
ACCEPT = HandshakeDecision(decision=HandshakeVerdict.ACCEPT, fingerprint="f" * 32, protocol=2)
MS = 1_000_000
TIMING = LinkTiming(
    heartbeat_interval_ns=100 * MS, heartbeat_timeout_ns=350 * MS,
    handshake_timeout_ns=5000 * MS, clock_burst=0, clock_ping_timeout_ns=1000 * MS,
    clock_refresh_ns=10_000 * MS, max_requests_in_flight=4, request_timeout_ns=250 * MS,
    max_frames_per_s=1000.0, max_chunks_per_s=100.0)
"""The shipped ``[policy]`` defaults, without a clock exchange (the timing tests add one)."""


def _protocol(timing: LinkTiming = TIMING, now_ns: int = 0) -> WardenProtocol:
    protocol = WardenProtocol("robot", wire.PROTOCOL_RANGE, LinkCounters(), timing)
    protocol.connect(now_ns)
    return protocol


def _accepted(timing: LinkTiming = TIMING) -> WardenProtocol:
    protocol = _protocol(timing)
    protocol.hello(HELLO, 0)
    protocol.receive_frame(wire.encode(wire.Offer(server_id="s", offer=OFFERED)), 10)
    protocol.on_decision(ACCEPT, 4, 10)
    return protocol


def _sent(outputs: list) -> list[wire.Message]:
    frames = [wire.decode_frame(o.data) for o in outputs if isinstance(o, Send)]
    return [wire.decode_body(frame, wire.message_type(frame)) for frame in frames]


def _chunk_frame(body: object) -> bytes:
    return wire.encode_chunk_body(msgspec.msgpack.encode(body))


def test_the_hello_carries_the_robots_side() -> None:
    protocol = WardenProtocol("robot", wire.PROTOCOL_RANGE, LinkCounters(), TIMING)
    assert protocol.connect(0) == [HelloDue()]  # no clock exchange: the hello is due at once
    (hello,) = _sent(protocol.hello(HELLO, 0))
    assert hello == wire.Hello(client_id="robot", protocol=wire.PROTOCOL_RANGE, hello=HELLO)
    assert protocol.hello(HELLO, 1) == []  # one hello per connection


def test_an_offer_is_handed_over_typed_once_per_connection() -> None:
    protocol = _protocol()
    frame = wire.encode(wire.Offer(server_id="s", offer=OFFERED))
    assert protocol.receive_frame(frame, 5) == []  # before the robot's hello: held
    assert protocol.hello(HELLO, 6)[-1] == OfferArrived(OFFERED)
    assert protocol.receive_frame(frame, 6) == []
    event = protocol.handshake_event(OFFERED, 7)
    assert event.t == 7 and event.offer is OFFERED
    protocol.connect(8)  # a new connection decides its own offer
    protocol.hello(HELLO, 8)
    assert protocol.receive_frame(frame, 8) == [OfferArrived(OFFERED)]


def test_the_cores_acceptance_goes_back_as_a_decision_and_opens_the_session() -> None:
    protocol = _protocol()
    outputs = protocol.on_decision(ACCEPT, 5, 10)
    assert _sent(outputs) == [wire.Decision(decision=ACCEPT, queue_epoch=5)]
    assert protocol.accepted and protocol.version == 2
    assert protocol.counters.handshakes_accepted == 1


def test_a_refusal_goes_back_and_ends_the_connection() -> None:
    protocol = _protocol()
    refused = HandshakeDecision(decision=HandshakeVerdict.REJECT, reasons=("SCHEMA_MISMATCH",))
    outputs = protocol.on_decision(refused, 0, 10)
    assert _sent(outputs) == [wire.Decision(decision=refused, queue_epoch=0)]
    assert outputs[-1] == Ended(ByeReason.HANDSHAKE_REJECTED, "SCHEMA_MISMATCH")
    assert not protocol.accepted and protocol.counters.handshakes_rejected == 1
    assert protocol.next_deadline() is None and protocol.timeout(10**12) == []


def test_a_chunk_outside_a_session_is_a_violation_that_ends_the_connection() -> None:
    protocol = _protocol()
    (ended,) = protocol.receive_frame(_chunk_frame({"chunk_id": "c"}), 1)
    assert ended == Ended(ByeReason.PROTOCOL_VIOLATION, "chunk before the session was accepted")
    assert protocol.counters.protocol_violations == 1
    assert protocol.receive_frame(_chunk_frame({"chunk_id": "c"}), 2) == []  # ended once


def test_a_chunk_of_the_session_is_queued_then_decoded_when_its_slot_comes() -> None:
    protocol = _accepted()
    assert protocol.receive_frame(_chunk_frame({"chunk_id": "c"}), 20) == [ChunksWaiting()]
    assert protocol.chunks_waiting == 1
    (fed,) = protocol.next_chunk(30)
    assert isinstance(fed, Feed)
    event = fed.event
    assert isinstance(event, ChunkEvent)
    assert event.t == 30 and isinstance(event.chunk, MalformedChunk)
    assert event.frame == msgspec.msgpack.encode({"chunk_id": "c"})
    assert protocol.counters.malformed == 1
    assert not isinstance(event.chunk, Chunk)
    assert protocol.next_chunk(31) == [] and protocol.chunks_waiting == 0


def test_chunk_decisions_are_counted_whichever_step_carried_them() -> None:
    protocol = _accepted()
    for decision in (Decision.ACCEPTED, Decision.BLENDED, Decision.REJECTED, Decision.IGNORED):
        assert protocol.on_decision(ChunkDecision(chunk_id="c", decision=decision), 4, 9) == []
    assert (protocol.counters.chunks_admitted, protocol.counters.chunks_refused) == (2, 2)


def test_an_observation_is_an_event_for_the_core_and_a_frame_for_the_peer() -> None:
    protocol = _accepted()
    sample = RobotSample(q=np.arange(6.0), task_phase="FREE_SPACE", qd=np.zeros(6))
    first = protocol.observe(sample, 100, 4)
    assert first[0] == Feed(ObservationEvent(t=100, observation_id="robot/1"))
    (observation,) = _sent(first)
    assert isinstance(observation, wire.Observation)
    assert (observation.observation_id, observation.t_event, observation.queue_epoch) == (
        "robot/1", 100, 4)
    assert wire.payload_vector(observation.q).tolist() == sample.q.tolist()
    second = protocol.observe(sample, 200, 4)
    assert second[0] == Feed(ObservationEvent(t=200, observation_id="robot/2"))


def test_stray_pongs_heartbeats_and_byes() -> None:
    protocol = _accepted()
    pong = wire.ClockPong(seq=1, t0=1, t_server=2)
    assert protocol.receive_frame(wire.encode(pong), 9) == []  # no ping in flight: dropped
    assert protocol.receive_frame(wire.encode(wire.Heartbeat(seq=1, t_send=0)), 10) == []
    (ended,) = protocol.receive_frame(wire.encode(wire.Bye(reason="shutdown")), 11)
    assert isinstance(ended, Ended) and ended.bye is None
    assert protocol.counters.byes_received == 1


@given(st.binary(max_size=200), st.booleans())
def test_any_bytes_are_outputs_never_a_crash(data: bytes, accepted: bool) -> None:
    protocol = _accepted() if accepted else _protocol()
    outputs = protocol.receive_frame(data, 1)
    assert all(isinstance(o, ChunksWaiting | OfferArrived | Ended) for o in outputs)
    assert len(outputs) <= 1
