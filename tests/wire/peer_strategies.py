"""Hypothesis strategies for the reference server's messages and chunk envelopes.

They build the server's own structs (``stubs/policy_server``) over the whole range the protocol
document allows: 64-bit integers (times, counts and offsets within their documented bounds), any
text, any float, arrays of any float64 values (NaN too:
array bytes compare exactly), every optional field absent or present.
"""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from peer import envelope as peer_env
from peer import handshake as peer_hs
from peer import protocol as peer

INT64 = st.integers(-(2**63), 2**63 - 1)
TIME = st.integers(-(2**63 - 1), 2**63 - 1)
COUNT = st.integers(0, 2**63 - 1)
OFFSET = st.integers(-(2**62), 2**62)
TEXT = st.text(max_size=12)
NAME = st.text(min_size=1, max_size=12)
FLOAT = st.floats(allow_nan=False)
"""Scalar floats compare by value after a round trip, so NaN (never equal) is left out."""
PAIR = st.tuples(INT64, INT64)
TEXTS = st.lists(TEXT, max_size=4).map(tuple)


def _payload(dims: int) -> st.SearchStrategy[peer.ArrayPayload]:
    shapes = hnp.array_shapes(min_dims=dims, max_dims=dims, min_side=1, max_side=6)
    return hnp.arrays(np.float64, shapes, elements=st.floats(width=64)).map(peer.array_payload)


VECTOR = _payload(1)
ACTIONS = _payload(2)


def _optional(strategy: st.SearchStrategy) -> st.SearchStrategy:  # type: ignore[type-arg]
    return st.none() | strategy


CLIENT_HELLO = st.builds(
    peer_hs.ClientHello, skill=TEXT, skill_version=TEXT, observation_keys=TEXTS,
    action_dim=INT64, action_units=TEXT, action_frame=TEXT, controller_mode=TEXT,
    control_rate_hz=FLOAT, calibration_epoch=TEXT, queue_epoch=INT64, protocol=PAIR,
    reason_codes=TEXTS,
)
OFFER = st.builds(
    peer_hs.HandshakeOffer, policy_checkpoint=TEXT, config_hash=TEXT, observation_keys=TEXTS,
    action_dim=INT64, action_units=TEXT, action_frame=TEXT, chunk_horizon=INT64, protocol=PAIR,
    skill=_optional(TEXT), skill_version=_optional(TEXT), controller_mode=_optional(TEXT),
    calibration_epoch=_optional(INT64 | TEXT), queue_epoch=_optional(INT64),
    reason_codes=_optional(TEXTS),
)
DECISION = st.builds(
    peer_hs.HandshakeDecision, decision=st.sampled_from(peer_hs.HandshakeVerdict),
    fingerprint=_optional(TEXT), reasons=TEXTS, protocol=_optional(INT64),
)

MESSAGES = st.one_of(
    st.builds(peer.Hello, client_id=TEXT, protocol=PAIR, hello=CLIENT_HELLO),
    st.builds(peer.Offer, server_id=TEXT, offer=OFFER),
    st.builds(peer.Decision, decision=DECISION, queue_epoch=COUNT),
    st.builds(peer.ClockPing, seq=COUNT, t0=TIME),
    st.builds(peer.ClockPong, seq=COUNT, t0=TIME, t_server=TIME),
    st.builds(peer.ClockReport, offset=OFFSET, round_trip=COUNT),
    st.builds(peer.Observation, observation_id=TEXT, t_event=TIME, queue_epoch=COUNT,
              task_phase=TEXT, q=VECTOR, qd=_optional(VECTOR), wrench=_optional(VECTOR),
              gripper=_optional(FLOAT)),
    st.builds(peer.Heartbeat, seq=COUNT, t_send=TIME),
    st.builds(peer.Bye, reason=st.sampled_from(peer.ByeReason), detail=TEXT),
)

STATE_FINGERPRINT = st.builds(
    peer_env.StateFingerprint, q=st.lists(FLOAT, max_size=7).map(tuple), hash=TEXT)

CHUNKS = st.builds(
    peer_env.ChunkEnvelope, chunk_id=NAME, sequence=COUNT, queue_epoch=COUNT,
    policy_checkpoint=NAME, config_hash=NAME, skill_version=NAME, task_phase=NAME,
    controller_mode=NAME, calibration_epoch=INT64 | TEXT, observation_id=NAME,
    first_action_time=TIME, action_dt=st.integers(1, 2**63 - 1), actions=ACTIONS,
    skill=_optional(TEXT), observation_event_time=_optional(TIME),
    observation_arrival_time=_optional(TIME), clock_domain=TEXT,
    inference_start=_optional(TIME), inference_end=_optional(TIME),
    server_send=_optional(TIME), max_observation_age=_optional(TIME),
    max_action_age=_optional(TIME), state_fingerprint=_optional(STATE_FINGERPRINT),
    replacement_policy=st.sampled_from(peer_env.ReplacementPolicy),
    fallback_id=_optional(TEXT), phase_markers=st.lists(st.integers(0, 2**63 - 1),
                                                        max_size=3).map(tuple),
    action_units=_optional(TEXT), action_frame=_optional(TEXT),
)
