"""The policy link's protocol object, driven directly with bytes and times: no socket, task or
clock (kernel/shell/link_protocol.py)."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from assurance.envelope import Chunk, MalformedChunk
from assurance.handshake import HandshakeDecision, HandshakeOffer, HandshakeVerdict
from kernel import wire
from kernel.core.effects import ChunkDecision
from kernel.core.events import ObservationEvent
from kernel.core.lines import Decision
from kernel.shell.link_protocol import (
    ChunkArrived,
    Ended,
    Feed,
    OfferArrived,
    PongArrived,
    Send,
    WardenProtocol,
)
from kernel.shell.link_types import LinkCounters, RobotSample
from kernel.wire import ByeReason, ProtocolViolation
from tests.core.test_handshake import HELLO, OFFER

OFFERED = msgspec.convert(OFFER, HandshakeOffer)
ACCEPT = HandshakeDecision(decision=HandshakeVerdict.ACCEPT, fingerprint="f" * 32, protocol=2)


def _protocol() -> WardenProtocol:
    protocol = WardenProtocol("robot", wire.PROTOCOL_RANGE, LinkCounters())
    protocol.begin()
    return protocol


def _accepted() -> WardenProtocol:
    protocol = _protocol()
    protocol.receive_frame(wire.encode(wire.Offer(server_id="s", offer=OFFERED)), 10)
    protocol.on_decision(ACCEPT, 4)
    return protocol


def _sent(outputs: list) -> list[wire.Message]:
    frames = [wire.decode_frame(o.data) for o in outputs if isinstance(o, Send)]
    return [wire.decode_body(frame, wire.message_type(frame)) for frame in frames]


def _chunk_frame(body: object) -> bytes:
    return wire.encode_chunk_body(msgspec.msgpack.encode(body))


def test_the_hello_carries_the_robots_side() -> None:
    (hello,) = _sent(_protocol().hello(HELLO))
    assert hello == wire.Hello(client_id="robot", protocol=wire.PROTOCOL_RANGE, hello=HELLO)


def test_an_offer_is_handed_over_typed_once_per_connection() -> None:
    protocol = _protocol()
    frame = wire.encode(wire.Offer(server_id="s", offer=OFFERED))
    assert protocol.receive_frame(frame, 5) == [OfferArrived(OFFERED)]
    assert protocol.receive_frame(frame, 6) == []
    event = protocol.handshake_event(OFFERED, 7)
    assert event.t == 7 and event.offer is OFFERED
    protocol.begin()  # a new connection decides its own offer
    assert protocol.receive_frame(frame, 8) == [OfferArrived(OFFERED)]


def test_the_cores_acceptance_goes_back_as_a_decision_and_opens_the_session() -> None:
    protocol = _protocol()
    outputs = protocol.on_decision(ACCEPT, 5)
    assert _sent(outputs) == [wire.Decision(decision=ACCEPT, queue_epoch=5)]
    assert protocol.accepted and protocol.version == 2
    assert protocol.counters.handshakes_accepted == 1


def test_a_refusal_goes_back_and_ends_the_connection() -> None:
    protocol = _protocol()
    refused = HandshakeDecision(decision=HandshakeVerdict.REJECT, reasons=("SCHEMA_MISMATCH",))
    outputs = protocol.on_decision(refused, 0)
    assert _sent(outputs) == [wire.Decision(decision=refused, queue_epoch=0)]
    assert outputs[-1] == Ended(ByeReason.HANDSHAKE_REJECTED, "SCHEMA_MISMATCH")
    assert not protocol.accepted and protocol.counters.handshakes_rejected == 1


def test_a_chunk_outside_a_session_is_a_violation() -> None:
    with pytest.raises(ProtocolViolation):
        _protocol().receive_frame(_chunk_frame({"chunk_id": "c"}), 1)


def test_a_chunk_of_the_session_is_queued_then_decoded_when_decided() -> None:
    protocol = _accepted()
    (arrived,) = protocol.receive_frame(_chunk_frame({"chunk_id": "c"}), 20)
    assert isinstance(arrived, ChunkArrived)
    event = protocol.chunk_event(arrived.frame, 30)
    assert event.t == 30 and isinstance(event.chunk, MalformedChunk)
    assert event.frame == msgspec.msgpack.encode({"chunk_id": "c"})
    assert protocol.counters.malformed == 1
    assert not isinstance(event.chunk, Chunk)


def test_chunk_decisions_are_counted_whichever_step_carried_them() -> None:
    protocol = _accepted()
    for decision in (Decision.ACCEPTED, Decision.BLENDED, Decision.REJECTED, Decision.IGNORED):
        assert protocol.on_decision(ChunkDecision(chunk_id="c", decision=decision), 4) == []
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


def test_pongs_heartbeats_and_byes() -> None:
    protocol = _accepted()
    pong = wire.ClockPong(seq=1, t0=1, t_server=2)
    assert protocol.receive_frame(wire.encode(pong), 9) == [PongArrived(pong, 9)]
    assert protocol.receive_frame(wire.encode(wire.Heartbeat(seq=1, t_send=0)), 10) == []
    (ended,) = protocol.receive_frame(wire.encode(wire.Bye(reason="shutdown")), 11)
    assert isinstance(ended, Ended) and ended.bye is None
    assert protocol.counters.byes_received == 1


@given(st.binary(max_size=200), st.booleans())
def test_any_bytes_are_outputs_or_a_violation_never_a_crash(data: bytes, accepted: bool) -> None:
    protocol = _accepted() if accepted else _protocol()
    try:
        outputs = protocol.receive_frame(data, 1)
    except ProtocolViolation:
        return
    assert all(isinstance(o, ChunkArrived | OfferArrived | PongArrived | Ended)
               for o in outputs)
