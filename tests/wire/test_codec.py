"""The wire codec: every message round-trips; bad frames are protocol violations, not crashes."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from assurance.envelope import ArrayPayload, Chunk, MalformedChunk, WireChunk, decode_wire_chunk
from assurance.handshake import HandshakeDecision, HandshakeOffer
from kernel.core.config import ClientSide
from kernel.wire import (
    MAX_FRAME_BYTES,
    Bye,
    ByeReason,
    ClockPing,
    ClockPong,
    ClockReport,
    ClockSample,
    Decision,
    Heartbeat,
    Hello,
    MessageType,
    Observation,
    Offer,
    ProtocolViolation,
    best_sample,
    decode_body,
    decode_frame,
    encode,
    encode_chunk,
    encode_raw,
    message_type,
    payload_vector,
    vector_payload,
)
from peer.envelope import ChunkEnvelope
from stubs.policy_server.faults import garbage_chunk_body, garbage_frame, oversized_frame

SIDE = ClientSide(skill="peg_insert", skill_version="3.1.0", observation_keys=("joint_pos",),
                  action_dim=6, action_units="rad", action_frame="joint",
                  controller_mode="joint_position", calibration_epoch="cal-12",
                  protocol=(1, 2), control_rate_hz=500.0)

MESSAGES = [
    Hello(client_id="r1", protocol=(1, 2), hello=SIDE.hello(3)),
    Offer(server_id="s1", offer=HandshakeOffer(
        policy_checkpoint="act-insert-2026-07", config_hash="cfg-9f2c",
        observation_keys=("joint_pos",), action_dim=6, action_units="rad", action_frame="joint",
        chunk_horizon=20, protocol=(1, 2), skill="peg_insert", queue_epoch=3)),
    Decision(decision=HandshakeDecision(decision="ACCEPT", fingerprint="ab", protocol=2),
             queue_epoch=4),
    ClockPing(seq=1, t0=10), ClockPong(seq=1, t0=10, t_server=-5),
    ClockReport(offset=7, round_trip=3),
    Observation(observation_id="o1", t_event=99, queue_epoch=4, task_phase="FREE_SPACE",
                q=vector_payload(np.arange(6.0)), gripper=0.5),
    Heartbeat(seq=2, t_send=11), Bye(reason=ByeReason.SHUTDOWN, detail="bye"),
]


@pytest.mark.parametrize("message", MESSAGES, ids=lambda m: type(m).__name__)
def test_every_message_round_trips(message: msgspec.Struct) -> None:
    frame = decode_frame(encode(message))
    assert decode_body(frame, message_type(frame)) == message


def test_chunk_body_reaches_the_envelope_decoder_unchanged() -> None:
    wire = _wire_chunk()
    frame = decode_frame(encode_chunk(wire))
    assert message_type(frame) is MessageType.CHUNK
    chunk = decode_wire_chunk(frame.body, 5)
    assert isinstance(chunk, Chunk)
    assert chunk.chunk_id == wire.chunk_id and chunk.client_receive == 5
    np.testing.assert_array_equal(chunk.actions, np.ones((3, 6)))


def test_broken_chunk_body_is_attributable_and_malformed() -> None:
    peer_chunk = msgspec.msgpack.decode(msgspec.msgpack.encode(_wire_chunk()), type=ChunkEnvelope)
    frame = decode_frame(encode_raw(MessageType.CHUNK, garbage_chunk_body(peer_chunk)))
    chunk = decode_wire_chunk(frame.body, 5)
    assert isinstance(chunk, MalformedChunk)
    assert chunk.chunk_id == "c1"


@pytest.mark.parametrize("data", [garbage_frame(), b"", "a text frame",
                                  msgspec.msgpack.encode({"type": "hello"})])
def test_undecodable_envelopes_are_violations(data: bytes | str) -> None:
    with pytest.raises(ProtocolViolation):
        decode_frame(data)


def test_unknown_type_and_too_new_type_are_violations() -> None:
    with pytest.raises(ProtocolViolation, match="unknown message type"):
        message_type(decode_frame(encode_raw("telemetry", b"\xc0")))
    frame = decode_frame(encode(ClockReport(offset=1, round_trip=1)))
    assert message_type(frame, version=2) is MessageType.CLOCK_REPORT
    with pytest.raises(ProtocolViolation, match="needs protocol 2"):
        message_type(frame, version=1)


def test_body_of_the_wrong_shape_is_a_violation() -> None:
    frame = decode_frame(encode_raw(MessageType.HELLO, msgspec.msgpack.encode({"x": 1})))
    with pytest.raises(ProtocolViolation, match="bad hello body"):
        decode_body(frame, message_type(frame))


def test_observation_refuses_fields_a_robot_does_not_measure() -> None:
    fields = msgspec.to_builtins(MESSAGES[6])
    frame = decode_frame(encode_raw(MessageType.OBSERVATION, msgspec.msgpack.encode(
        {**fields, "goal": [0.1] * 6})))
    with pytest.raises(ProtocolViolation):
        decode_body(frame, MessageType.OBSERVATION)


def test_state_vectors_are_checked() -> None:
    np.testing.assert_array_equal(payload_vector(vector_payload((1.0, 2.0)), 2), [1.0, 2.0])
    with pytest.raises(ProtocolViolation, match="expected 6"):
        payload_vector(vector_payload((1.0, 2.0)), 6)
    bad = msgspec.structs.replace(vector_payload((1.0, 2.0)), data=b"\x00" * 3)
    with pytest.raises(ProtocolViolation, match="byte length"):
        payload_vector(bad)


def test_oversized_frame_is_over_the_limit() -> None:
    assert len(oversized_frame()) > MAX_FRAME_BYTES


def test_clock_sample_arithmetic_and_min_round_trip() -> None:
    # The server's clock reads 1000 when ours reads 50 at the midpoint: t_client = t_server - 950.
    sample = ClockSample(t0=40, t_server=1000, t1=60)
    assert (sample.offset, sample.round_trip) == (-950, 20)
    samples = [ClockSample(0, 1000, 30), sample, ClockSample(100, 2000, 180)]
    assert best_sample(samples) is sample
    assert best_sample([ClockSample(10, 0, 5)]) is None


def _wire_chunk() -> WireChunk:
    return WireChunk(
        chunk_id="c1", sequence=1, queue_epoch=0, policy_checkpoint="p", config_hash="c",
        skill_version="1", task_phase="FREE_SPACE", controller_mode="joint_position",
        calibration_epoch="cal", observation_id="o1", first_action_time=0, action_dt=10,
        actions=ArrayPayload.from_array(np.ones((3, 6))),
    )
