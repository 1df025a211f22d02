"""The openpi link's protocol object, driven with frames an unmodified openpi server sent
(tests/interop/openpi/frames) and with times: no socket, task or clock
(kernel/shell/link_openpi.py)."""

from __future__ import annotations

import hashlib

import msgspec
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from assurance.envelope import Chunk
from assurance.handshake import HandshakeDecision, HandshakeVerdict, evaluate
from kernel.core.effects import ChunkDecision
from kernel.core.events import ChunkEvent, ObservationEvent
from kernel.core.lines import Decision
from kernel.openpi_wire import decode_reply
from kernel.shell.link_openpi import CONFIG_HASH_PREFIX, OpenpiLink, OpenpiProtocol
from kernel.shell.link_protocol import (
    ChunksWaiting,
    Ended,
    Feed,
    HelloDue,
    ObservationDue,
    OfferArrived,
    Send,
)
from kernel.shell.link_types import LinkCounters, RobotSample
from kernel.wire import ByeReason
from tests.core.test_handshake import HELLO
from tests.interop.openpi.test_openpi_wire import frame
from tests.shell.test_link_protocol import MS, TIMING

METADATA, REPLY = frame("metadata.msgpack"), frame("reply1.msgpack")  # a 10×7 reply
LINK = OpenpiLink(policy_checkpoint="pi05-insert@unattested", action_dt_ns=20 * MS,
                  max_horizon=50, prompt="insert the peg")
DIGEST = CONFIG_HASH_PREFIX + hashlib.sha256(METADATA).hexdigest()
ACCEPT = HandshakeDecision(decision=HandshakeVerdict.ACCEPT, fingerprint="f" * 32, protocol=3)
SAMPLE = RobotSample(q=np.linspace(0.1, 0.6, 6), task_phase="PRE_CONTACT", gripper=0.04)


def _protocol() -> OpenpiProtocol:
    protocol = OpenpiProtocol("robot", LINK, LinkCounters(), TIMING)
    assert protocol.connect(0) == [HelloDue()]
    return protocol


def _accepted() -> OpenpiProtocol:
    protocol = _protocol()
    protocol.hello(HELLO, 1)
    protocol.receive_frame(METADATA, 2)
    assert protocol.on_decision(ACCEPT, 4, 3) == [] and protocol.accepted
    return protocol


def _asked(protocol: OpenpiProtocol, now_ns: int) -> list:
    assert protocol.request(now_ns) == [ObservationDue()]
    return protocol.observe(SAMPLE, now_ns, 4)


def test_the_offer_is_the_robots_schema_the_declared_checkpoint_and_the_metadatas_digest(
        ) -> None:
    protocol = _protocol()
    assert protocol.hello(HELLO, 1) == []  # no metadata yet: nothing to offer
    [arrived] = protocol.receive_frame(METADATA, 2)
    assert isinstance(arrived, OfferArrived)
    offer = arrived.offer
    assert (offer.policy_checkpoint, offer.config_hash) == (LINK.policy_checkpoint, DIGEST)
    assert (offer.observation_keys, offer.action_dim, offer.action_units, offer.action_frame,
            offer.chunk_horizon, offer.protocol) == (
        HELLO.observation_keys, 7, HELLO.action_units, HELLO.action_frame, 50, HELLO.protocol)
    decision, _ = evaluate(HELLO, offer, frozenset({(LINK.policy_checkpoint, DIGEST)}))
    assert decision.decision is HandshakeVerdict.ACCEPT
    changed, _ = evaluate(HELLO, msgspec.structs.replace(offer, config_hash=DIGEST[:-1] + "0"),
                          frozenset({(LINK.policy_checkpoint, DIGEST)}))
    assert changed.reasons == ("CHECKPOINT_NOT_ALLOWED",)  # another server's configuration


def test_one_observation_at_a_time_in_openpis_own_layout() -> None:
    protocol = _accepted()
    fed, sent = _asked(protocol, 10 * MS)
    assert isinstance(fed, Feed) and isinstance(fed.event, ObservationEvent)
    assert fed.event.observation_id == "robot/1" and fed.event.t == 10 * MS
    assert isinstance(sent, Send)
    observation = msgspec.msgpack.decode(sent.data)
    state = observation["observation/state"]
    assert (state[b"__ndarray__"], state[b"dtype"], state[b"shape"]) == (True, "<f8", [7])
    assert np.frombuffer(state[b"data"]).tolist() == [*SAMPLE.q.tolist(), 0.04]
    assert observation["prompt"] == "insert the peg"
    assert protocol.request(11 * MS) == []  # one in flight: the next waits for its reply
    assert protocol.counters.requests_waited == 1


def test_a_reply_becomes_a_chunk_made_from_its_request_on_the_robots_clock() -> None:
    protocol = _accepted()
    _asked(protocol, 10 * MS)
    protocol.request(11 * MS)  # wanted again: due once the reply is fed
    assert protocol.receive_frame(REPLY, 60 * MS) == [ChunksWaiting()]
    fed, due = protocol.next_chunk(61 * MS)
    assert due == ObservationDue()
    assert isinstance(fed, Feed) and isinstance(fed.event, ChunkEvent)
    chunk = fed.event.chunk
    assert isinstance(chunk, Chunk)
    assert (chunk.chunk_id, chunk.sequence, chunk.observation_id, chunk.queue_epoch) == (
        "robot/openpi-1", 1, "robot/1", 4)
    assert (chunk.policy_checkpoint, chunk.config_hash, chunk.task_phase) == (
        LINK.policy_checkpoint, DIGEST, "PRE_CONTACT")
    assert (chunk.skill, chunk.skill_version, chunk.controller_mode, chunk.calibration_epoch) == (
        HELLO.skill, HELLO.skill_version, HELLO.controller_mode, HELLO.calibration_epoch)
    assert chunk.times["first_action_time"] == chunk.times["observation_event_time"] == 10 * MS
    assert chunk.times["inference_start"] is None and chunk.times["inference_end"] is None
    assert chunk.times["action_dt"] == 20 * MS and chunk.client_receive == 61 * MS
    assert chunk.fingerprint_q == tuple(SAMPLE.q.tolist())
    np.testing.assert_array_equal(chunk.actions, decode_reply(REPLY, 7).actions)
    admitted = ChunkDecision(chunk_id="robot/openpi-1", decision=Decision.ACCEPTED)
    protocol.on_decision(admitted, 4, 62 * MS)
    assert (protocol.counters.chunks_in, protocol.counters.chunks_admitted) == (1, 1)


def test_a_server_traceback_ends_the_link_with_its_last_line() -> None:
    protocol = _accepted()
    _asked(protocol, 10 * MS)
    [ended] = protocol.receive_frame(frame("reply3.txt").decode(), 20 * MS)
    assert ended == Ended(None, "server error: RuntimeError: scripted failure: the third request")
    assert protocol.next_deadline() is None and protocol.request(30 * MS) == []


def test_frames_openpi_does_not_send_are_protocol_violations() -> None:
    unasked = _accepted()
    [ended] = unasked.receive_frame(REPLY, 20 * MS)
    assert ended == Ended(ByeReason.PROTOCOL_VIOLATION, "a reply to no request")
    other_shape = _accepted()
    _asked(other_shape, 10 * MS)
    other_shape._hello = msgspec.structs.replace(HELLO, action_dim=6)  # the robot maps 6
    [ended] = other_shape.receive_frame(REPLY, 20 * MS)
    assert ended == Ended(ByeReason.PROTOCOL_VIOLATION,
                          "actions have 7 dimensions, the manifest maps 6")
    assert other_shape.counters.protocol_violations == 1


def test_no_metadata_in_time_and_no_reply_in_time_end_the_link() -> None:
    protocol = _protocol()
    assert protocol.next_deadline() == TIMING.handshake_timeout_ns
    assert protocol.timeout(TIMING.handshake_timeout_ns) == [
        Ended(ByeReason.HANDSHAKE_TIMEOUT, "no metadata frame in time")]
    silent = _accepted()
    _asked(silent, 10 * MS)
    assert silent.next_deadline() == 10 * MS + TIMING.request_timeout_ns
    assert silent.timeout(10 * MS + TIMING.request_timeout_ns - 1) == []
    [ended] = silent.timeout(10 * MS + TIMING.request_timeout_ns)
    assert ended.bye is ByeReason.HEARTBEAT_TIMEOUT and silent.counters.link_timeouts == 1


def test_a_rejected_handshake_ends_the_link_and_nothing_is_sent_for_it() -> None:
    protocol = _protocol()
    protocol.hello(HELLO, 1)
    protocol.receive_frame(METADATA, 2)
    rejected = HandshakeDecision(decision=HandshakeVerdict.REJECT,
                                 reasons=("CHECKPOINT_NOT_ALLOWED",))
    assert protocol.on_decision(rejected, 4, 3) == [
        Ended(None, "handshake rejected: CHECKPOINT_NOT_ALLOWED")]
    assert not protocol.accepted and protocol.counters.handshakes_rejected == 1
    assert OpenpiProtocol.says_goodbye is False


_LEAF = (st.none() | st.integers(-(2**63), 2**63 - 1) | st.floats()
         | st.binary(max_size=64))
_VALUE = st.recursive(_LEAF, lambda inner: st.lists(inner, max_size=4)
                      | st.dictionaries(st.binary(max_size=12), inner, max_size=4),
                      max_leaves=12)
_MAPS = st.dictionaries(st.sampled_from(["actions", "server_timing", "x"]), _VALUE)


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.binary(max_size=4096), st.text(max_size=200),
                 st.builds(msgspec.msgpack.encode, _MAPS)))
def test_whatever_the_server_sends_ends_the_link_or_is_one_checked_chunk(
        data: bytes | str) -> None:
    protocol = _accepted()
    _asked(protocol, 10 * MS)
    outputs = protocol.receive_frame(data, 20 * MS)
    assert outputs == [ChunksWaiting()] or (len(outputs) == 1 and isinstance(outputs[0], Ended))
    if outputs == [ChunksWaiting()]:
        [fed] = protocol.next_chunk(21 * MS)
        assert isinstance(fed.event.chunk, Chunk)
