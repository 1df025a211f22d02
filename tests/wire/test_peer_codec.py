"""Cross-check of two independent codecs: warden's (``kernel.wire``, ``assurance.envelope``,
``assurance.handshake``) and the reference server's (``stubs/policy_server``), each written
against ``docs/protocol.md``. Each side decodes what the other encodes to the same values, and
both derive the same fingerprint: a mistake in one codec shows up here as a disagreement."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import msgspec
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from assurance import handshake as warden_hs
from assurance.envelope import Chunk, WireChunk, decode_wire_chunk
from kernel import wire
from peer import envelope as peer_env
from peer import handshake as peer_hs
from peer import protocol as peer
from stubs.policy_server.config import ServerConfig
from tests.wire.peer_strategies import CHUNKS, CLIENT_HELLO, MESSAGES, OFFER

SERVER_PACKAGE = Path(__file__).parents[2] / "stubs" / "policy_server"


def test_the_server_shares_no_codec_with_warden() -> None:
    """Nothing of warden's codec: the server imports neither the kernel nor the assurance
    package (its forward kinematics come through stubs.robot_model)."""
    imported = set()
    for source in SERVER_PACKAGE.glob("*.py"):
        for node in ast.walk(ast.parse(source.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                imported.add(node.module)
            elif isinstance(node, ast.Import):
                imported.update(alias.name for alias in node.names)
    warden = {name for name in imported if name.split(".")[0] in ("kernel", "assurance")}
    assert warden == set()


# -- messages ----------------------------------------------------------------------------------


def _warden_twin(message: msgspec.Struct) -> msgspec.Struct:
    """The same message as warden's struct, built from the server's field by field."""
    return msgspec.convert(message, getattr(wire, type(message).__name__), from_attributes=True)


@given(MESSAGES)
def test_server_messages_decode_in_warden_to_the_same_values(message: msgspec.Struct) -> None:
    frame = wire.decode_frame(peer.encode(message))
    decoded = wire.decode_body(frame, wire.message_type(frame))
    assert type(decoded).__name__ == type(message).__name__
    assert msgspec.to_builtins(decoded) == msgspec.to_builtins(message)


@given(MESSAGES)
def test_warden_messages_decode_in_the_server_to_the_same_values(message: msgspec.Struct) -> None:
    frame = peer.decode_frame(wire.encode(_warden_twin(message)))
    assert peer.decode_body(frame, peer.message_type(frame)) == message


def test_both_sides_write_the_documented_frame_bytes() -> None:
    documented = bytes.fromhex("92 a9") + b"heartbeat" + bytes.fromhex("82 a3") + b"seq" + (
        bytes.fromhex("01 a6") + b"t_send" + bytes.fromhex("05"))
    assert peer.encode(peer.Heartbeat(seq=1, t_send=5)) == documented
    assert wire.encode(wire.Heartbeat(seq=1, t_send=5)) == documented


@pytest.mark.parametrize(("data", "version"), [
    (b"\xc1garbage", None),
    ("a text frame", None),
    (msgspec.msgpack.encode({"type": "hello"}), None),
    (wire.encode_raw("telemetry", b"\xc0"), None),
    (wire.encode(wire.ClockReport(offset=1, round_trip=1)), 1),
    (wire.encode_raw("hello", msgspec.msgpack.encode({"client_id": "r"})), None),
    (wire.encode_raw("observation", msgspec.msgpack.encode({
        "observation_id": "o", "t_event": 0, "queue_epoch": 0, "task_phase": "FREE_SPACE",
        "q": {"dtype": "<f8", "shape": [0], "data": b""}, "goal": [0.1]})), None),
    (bytes.fromhex("92 a3 ff fe fd c0"), None),
    (bytes.fromhex("92 a9") + b"heartbeat" + b"\x91" * 100_000, None),
    (wire.encode_raw("bye", bytes.fromhex("81 a6") + b"reason" + bytes.fromhex("a2 ff fe")),
     None),
    (wire.encode_raw("clock_pong", msgspec.msgpack.encode(
        {"seq": 1, "t0": 0, "t_server": 2**64 - 1})), None),
    (wire.encode_raw("heartbeat", msgspec.msgpack.encode({"seq": -1, "t_send": 0})), None),
    (wire.encode_raw("clock_report", msgspec.msgpack.encode(
        {"offset": 2**62 + 1, "round_trip": 0})), 2),
], ids=["not_msgpack", "text", "not_a_frame", "unknown_type", "too_new", "missing_field",
        "unknown_observation_field", "invalid_utf8_type", "nested_too_deep",
        "invalid_utf8_body", "time_beyond_int64", "negative_sequence", "offset_too_large"])
def test_both_sides_call_the_same_frames_violations(data: bytes | str, version: int | None,
                                                    ) -> None:
    with pytest.raises(wire.ProtocolViolation):
        frame = wire.decode_frame(data)
        wire.decode_body(frame, wire.message_type(frame, version))
    with pytest.raises(peer.ProtocolViolation):
        frame = peer.decode_frame(data)
        peer.decode_body(frame, peer.message_type(frame, version))


# -- chunk envelopes ---------------------------------------------------------------------------


@given(CHUNKS)
def test_server_chunks_decode_in_warden_to_the_same_values(chunk: peer_env.ChunkEnvelope) -> None:
    frame = wire.decode_frame(peer_env.encode_chunk_frame(chunk))
    assert wire.message_type(frame) is wire.MessageType.CHUNK
    as_struct = msgspec.msgpack.decode(frame.body, type=WireChunk)
    assert msgspec.to_builtins(as_struct) == msgspec.to_builtins(chunk)
    decoded = decode_wire_chunk(frame.body, client_receive=7)
    assert isinstance(decoded, Chunk), decoded
    np.testing.assert_array_equal(decoded.actions, peer_env.action_array(chunk.actions))
    assert decoded.calibration_epoch == str(chunk.calibration_epoch)
    assert decoded.times["first_action_time"] == chunk.first_action_time
    assert decoded.times["server_send"] == chunk.server_send


@given(CHUNKS, st.sampled_from(["<f8", ">f8", "<f4"]))
def test_warden_chunks_decode_in_the_server_to_the_same_values(
    chunk: peer_env.ChunkEnvelope, dtype: str,
) -> None:
    with np.errstate(over="ignore"):  # a large float64 becomes an infinite float32: fine here
        narrowed = peer_env.action_array(chunk.actions).astype(dtype)
    sent = msgspec.structs.replace(chunk, actions=peer.array_payload(narrowed, dtype))
    frame = peer.decode_frame(wire.encode_chunk(msgspec.convert(sent, WireChunk,
                                                                from_attributes=True)))
    assert peer.message_type(frame) is peer.MessageType.CHUNK
    decoded, decoded_actions = peer_env.decode_chunk_body(frame.body)
    assert decoded == sent
    np.testing.assert_array_equal(decoded_actions, narrowed.astype(np.float64))


@pytest.mark.parametrize(("field", "value"), [
    ("sequence", -1), ("sequence", 2**63), ("queue_epoch", -1), ("queue_epoch", 2**64 - 1)])
def test_counts_outside_their_range_are_malformed_on_both_sides(field: str, value: int) -> None:
    actions = peer.array_payload(np.ones((2, 6)))
    chunk = peer_env.ChunkEnvelope(
        chunk_id="c", sequence=1, queue_epoch=0, policy_checkpoint="p", config_hash="h",
        skill_version="1", task_phase="FREE_SPACE", controller_mode="joint_position",
        calibration_epoch="cal", observation_id="o", first_action_time=0, action_dt=1,
        actions=actions)
    body = msgspec.msgpack.encode({**msgspec.to_builtins(chunk, builtin_types=(bytes,)),
                                   field: value})
    decoded = decode_wire_chunk(body, 0)
    assert not isinstance(decoded, Chunk) and field in decoded.detail
    with pytest.raises(msgspec.ValidationError):
        msgspec.msgpack.decode(body, type=peer_env.ChunkEnvelope)


def test_a_nonfinite_action_reaches_warden_as_nonfinite_not_malformed() -> None:
    actions = np.ones((4, 6))
    actions[2, 3] = np.nan
    decoded = decode_wire_chunk(wire.decode_frame(chunk_frame_of(actions)).body, 0)
    assert isinstance(decoded, Chunk) and decoded.nonfinite == ("actions",)
    assert np.isnan(decoded.actions[2, 3]) and decoded.actions.shape == (4, 6)


def chunk_frame_of(actions: np.ndarray, **changes: object) -> bytes:
    source = ServerConfig().chunk_source()
    proposal = peer_env.Proposal(
        chunk_id="policy-ref-e3-s9", sequence=9, queue_epoch=3, task_phase="PRE_CONTACT",
        observation_id="robot/12", observed_q=np.linspace(-1.0, 1.0, 6), actions=actions,
        first_action_time=5_000_000, observation_event_time=1_000_000,
        observation_arrival_time=1_200_000, inference_start=1_300_000,
        inference_end=2_300_000, server_send=2_400_000)
    return peer_env.chunk_frame(source, dataclasses.replace(proposal, **changes))


def test_chunk_frame_carries_the_source_and_the_proposal_to_warden() -> None:
    actions = np.arange(60.0).reshape(10, 6) / 100.0
    body = wire.decode_frame(chunk_frame_of(actions)).body
    assert msgspec.msgpack.decode(body, type=WireChunk).actions.dtype == "<f8"  # as documented
    decoded = decode_wire_chunk(body, 3_000_000)
    assert isinstance(decoded, Chunk)
    config = ServerConfig()
    assert (decoded.chunk_id, decoded.sequence, decoded.queue_epoch) == ("policy-ref-e3-s9", 9, 3)
    assert (decoded.policy_checkpoint, decoded.config_hash, decoded.skill_version) == (
        config.policy_checkpoint, config.config_hash, config.skill_version)
    assert (decoded.clock_domain, decoded.task_phase, decoded.fallback_id) == (
        wire.SERVER_CLOCK_DOMAIN, "PRE_CONTACT", "safe_hold")
    assert decoded.times["action_dt"] == round(config.action_dt_ms * 1e6)
    assert decoded.times["max_action_age"] == round(config.max_action_age_ms * 1e6)
    assert decoded.fingerprint_q == tuple(np.linspace(-1.0, 1.0, 6))
    np.testing.assert_array_equal(decoded.actions, actions)


# -- the handshake fingerprint -----------------------------------------------------------------


def _both_fingerprints(hello: peer_hs.ClientHello, offer: peer_hs.HandshakeOffer,
                       version: int) -> tuple[str, str]:
    warden = warden_hs.fingerprint(
        msgspec.convert(hello, warden_hs.ClientHello, from_attributes=True),
        msgspec.convert(offer, warden_hs.HandshakeOffer, from_attributes=True), version)
    return peer_hs.fingerprint(hello, offer, version), warden


@given(CLIENT_HELLO, OFFER, st.integers(-(2**63), 2**64 - 1))
def test_both_sides_derive_the_same_fingerprint(hello: peer_hs.ClientHello,
                                                offer: peer_hs.HandshakeOffer,
                                                version: int) -> None:
    ours, theirs = _both_fingerprints(hello, offer, version)
    assert ours == theirs and len(ours) == 32


DEFAULT_HELLO = peer_hs.ClientHello(
    skill="peg_insert", skill_version="3.1.0",
    observation_keys=("wrist_rgb", "scene_rgb", "joint_pos", "wrench"), action_dim=6,
    action_units="rad", action_frame="joint", controller_mode="joint_position",
    control_rate_hz=500.0, calibration_epoch="cal-12", queue_epoch=0, protocol=(1, 2),
    reason_codes=("MALFORMED",),
)


def test_the_documented_test_vector() -> None:
    ours, theirs = _both_fingerprints(DEFAULT_HELLO, ServerConfig().offer(0), 2)
    assert ours == theirs == "f498a141288010b277bbe8c9b5da82a1"


HASHED_CHANGES = [
    ("hello", "observation_keys", ("joint_pos",)), ("hello", "action_dim", 7),
    ("hello", "action_units", "m"), ("hello", "action_frame", "base_delta"),
    ("hello", "skill", "peg_remove"), ("hello", "skill_version", "3.1.1"),
    ("hello", "controller_mode", "joint_velocity"), ("hello", "control_rate_hz", 250.0),
    ("hello", "calibration_epoch", "cal-13"), ("hello", "queue_epoch", 1),
    ("offer", "policy_checkpoint", "act-insert-2026-08"), ("offer", "config_hash", "cfg-0000"),
    ("offer", "chunk_horizon", 21), ("version", "", 1),
]


@pytest.mark.parametrize(("side", "name", "value"), HASHED_CHANGES,
                         ids=[f"{side}.{name}" if name else side
                              for side, name, _ in HASHED_CHANGES])
def test_a_changed_field_changes_the_fingerprint_on_both_sides(
    side: str, name: str, value: object,
) -> None:
    hello, offer, version = DEFAULT_HELLO, ServerConfig().offer(0), 2
    before = _both_fingerprints(hello, offer, version)
    if side == "hello":
        hello = msgspec.structs.replace(hello, **{name: value})
    elif side == "offer":
        offer = msgspec.structs.replace(offer, **{name: value})
    else:
        version = int(value)  # type: ignore[call-overload]
    ours, theirs = _both_fingerprints(hello, offer, version)
    assert ours == theirs
    assert ours != before[0]


def test_fields_outside_the_fingerprint_leave_it_unchanged() -> None:
    offer = ServerConfig().offer(0)
    before = _both_fingerprints(DEFAULT_HELLO, offer, 2)
    hello = msgspec.structs.replace(DEFAULT_HELLO, reason_codes=(), protocol=(2, 2))
    offer = msgspec.structs.replace(offer, queue_epoch=5, skill="told", reason_codes=("X",))
    assert _both_fingerprints(hello, offer, 2) == before


def test_a_whole_number_control_rate_is_hashed_as_a_float() -> None:
    """An integer 500 on the wire is decoded as 500.0, and hashed as float64 by both sides."""
    body = msgspec.msgpack.encode({**msgspec.to_builtins(DEFAULT_HELLO), "control_rate_hz": 500})
    hello = msgspec.msgpack.decode(body, type=peer_hs.ClientHello)
    assert _both_fingerprints(hello, ServerConfig().offer(0), 2)[0] == (
        "f498a141288010b277bbe8c9b5da82a1")


@given(st.recursive(st.integers(-(2**63), 2**64 - 1) | st.floats(allow_nan=False) | st.text(),
                    lambda items: st.lists(items, max_size=20), max_leaves=40))
def test_canonical_bytes_are_what_msgspec_writes(value: object) -> None:
    assert peer_hs.canonical_bytes(value) == msgspec.msgpack.encode(value)  # type: ignore[arg-type]


def test_warden_accepts_the_server_offer_with_the_server_fingerprint() -> None:
    offer = ServerConfig().offer(0)
    hello = msgspec.convert(DEFAULT_HELLO, warden_hs.ClientHello, from_attributes=True)
    allowlist = frozenset({(offer.policy_checkpoint, offer.config_hash)})
    decision, _ = warden_hs.evaluate(hello, msgspec.to_builtins(offer), allowlist)
    assert decision.decision == "ACCEPT" and decision.protocol == 2
    assert decision.fingerprint == peer_hs.fingerprint(DEFAULT_HELLO, offer, 2)
