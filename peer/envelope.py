"""The chunk envelope as this server writes it, from ``docs/protocol.md`` ("The chunk body").

:func:`chunk_frame` is the one way a chunk becomes bytes: the server sends what it returns,
and an in-process stand-in for the server (a lockstep run) that calls it produces the very
same bytes without a network.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from enum import StrEnum
from typing import Annotated

import msgspec
import numpy as np

from peer.protocol import (
    SERVER_CLOCK_DOMAIN,
    ArrayPayload,
    MessageType,
    array_payload,
    encode_raw,
)


class ReplacementPolicy(StrEnum):
    REPLACE = "replace"
    APPEND = "append"
    BLEND = "blend"


class ActionFrame(StrEnum):
    JOINT = "joint"
    BASE_DELTA = "base_delta"
    """TCP displacements from the observed pose, in base-frame axes."""


class ActionUnits(StrEnum):
    RADIANS = "rad"
    METRES = "m"
    """Cartesian: a displacement only, the observed orientation held."""
    METRES_RADIANS = "m+rad"
    """Cartesian: a displacement and a rotation vector."""


INT64_MAX = 2**63 - 1
Text = Annotated[str, msgspec.Meta(min_length=1)]
Time = Annotated[int, msgspec.Meta(ge=-INT64_MAX, le=INT64_MAX)]
Step = Annotated[int, msgspec.Meta(gt=0, le=INT64_MAX)]
Count = Annotated[int, msgspec.Meta(ge=0, le=INT64_MAX)]
ActionIndex = Annotated[int, msgspec.Meta(ge=0)]


class StateFingerprint(msgspec.Struct, frozen=True, kw_only=True):
    q: tuple[float, ...]
    hash: str = ""


class ChunkEnvelope(msgspec.Struct, frozen=True, kw_only=True):
    """The body of a ``chunk`` frame. Times are integer nanoseconds in ``clock_domain``."""

    chunk_id: Text
    sequence: Count
    queue_epoch: Count
    policy_checkpoint: Text
    config_hash: Text
    skill_version: Text
    task_phase: Text
    controller_mode: Text
    calibration_epoch: int | str
    observation_id: Text
    first_action_time: Time
    action_dt: Step
    actions: ArrayPayload
    skill: str | None = None
    observation_event_time: Time | None = None
    observation_arrival_time: Time | None = None
    clock_domain: str = "client"
    inference_start: Time | None = None
    inference_end: Time | None = None
    server_send: Time | None = None
    max_observation_age: Time | None = None
    max_action_age: Time | None = None
    state_fingerprint: StateFingerprint | None = None
    replacement_policy: ReplacementPolicy = ReplacementPolicy.REPLACE
    fallback_id: str | None = None
    phase_markers: tuple[ActionIndex, ...] = ()
    action_units: str | None = None
    action_frame: str | None = None
    rtc_delay: int | None = None


@dataclass(frozen=True, slots=True)
class ChunkSource:
    """What every chunk of a session repeats: who proposes, for what, and how."""

    policy_checkpoint: str
    config_hash: str
    skill: str | None
    skill_version: str
    controller_mode: str
    calibration_epoch: int | str
    action_units: str
    action_frame: str
    action_dt_ns: int
    max_observation_age_ns: int | None
    max_action_age_ns: int | None
    replacement_policy: ReplacementPolicy = ReplacementPolicy.REPLACE
    clock_domain: str = SERVER_CLOCK_DOMAIN
    fallback_id: str | None = "safe_hold"


@dataclass(frozen=True, slots=True, eq=False)
class Proposal:
    """The policy's answer to one observation. Times are ns in the source's clock domain."""

    chunk_id: str
    sequence: int
    queue_epoch: int
    task_phase: str
    observation_id: str
    observed_q: np.ndarray
    """The state the actions were conditioned on (sent as the state fingerprint)."""
    actions: np.ndarray
    """H × D, sent as little-endian float64."""
    first_action_time: int
    observation_event_time: int | None = None
    observation_arrival_time: int | None = None
    inference_start: int | None = None
    inference_end: int | None = None
    server_send: int | None = None
    rtc_delay: int | None = None
    """Its first ``rtc_delay`` actions repeat the committed prefix (real-time chunking)."""


_ENCODER = msgspec.msgpack.Encoder()
_DECODER = msgspec.msgpack.Decoder(ChunkEnvelope)


def chunk_frame(source: ChunkSource, proposal: Proposal) -> bytes:
    """The encoded ``chunk`` frame of one proposal: exactly the bytes the server sends."""
    return encode_chunk_frame(chunk_envelope(source, proposal))


def chunk_envelope(source: ChunkSource, proposal: Proposal) -> ChunkEnvelope:
    return ChunkEnvelope(
        chunk_id=proposal.chunk_id, sequence=proposal.sequence, queue_epoch=proposal.queue_epoch,
        policy_checkpoint=source.policy_checkpoint, config_hash=source.config_hash,
        skill=source.skill, skill_version=source.skill_version, task_phase=proposal.task_phase,
        controller_mode=source.controller_mode, calibration_epoch=source.calibration_epoch,
        observation_id=proposal.observation_id, first_action_time=proposal.first_action_time,
        action_dt=source.action_dt_ns, actions=array_payload(proposal.actions),
        observation_event_time=proposal.observation_event_time,
        observation_arrival_time=proposal.observation_arrival_time,
        clock_domain=source.clock_domain, inference_start=proposal.inference_start,
        inference_end=proposal.inference_end, server_send=proposal.server_send,
        max_observation_age=source.max_observation_age_ns,
        max_action_age=source.max_action_age_ns,
        state_fingerprint=state_fingerprint(proposal.observed_q),
        replacement_policy=source.replacement_policy, fallback_id=source.fallback_id,
        action_units=source.action_units, action_frame=source.action_frame,
        rtc_delay=proposal.rtc_delay,
    )


def state_fingerprint(q: np.ndarray) -> StateFingerprint:
    """The joint vector and its BLAKE2b-64 over little-endian float64 (informational: the
    robot compares the vector, not the hash)."""
    canonical = np.ascontiguousarray(q, dtype="<f8").reshape(-1)
    digest = hashlib.blake2b(canonical.tobytes(), digest_size=8).hexdigest()
    return StateFingerprint(q=tuple(canonical.tolist()), hash=digest)


def encode_chunk_body(chunk: ChunkEnvelope) -> bytes:
    return _ENCODER.encode(chunk)


def encode_chunk_frame(chunk: ChunkEnvelope) -> bytes:
    return chunk_body_frame(encode_chunk_body(chunk))


def chunk_body_frame(body: bytes) -> bytes:
    """A ``chunk`` frame around any body (one MessagePack object): the faults' broken ones."""
    return encode_raw(MessageType.CHUNK, body)


def decode_chunk_body(body: bytes) -> tuple[ChunkEnvelope, np.ndarray]:
    """A chunk body and its actions as float64 (the server never receives one; its tests do).

    Raises:
        msgspec.ValidationError: a missing field, a wrong type, a value outside its range.
        ValueError: actions that are not a non-empty 2-D float array filled by their bytes.
    """
    chunk = _DECODER.decode(body)
    return chunk, action_array(chunk.actions)


def action_array(payload: ArrayPayload) -> np.ndarray:
    """The H × D actions as float64, whatever float dtype they were sent in.

    Raises:
        ValueError: another dtype or shape, or bytes that do not fill it.
    """
    try:
        dtype = np.dtype(payload.dtype)
    except (TypeError, ValueError, SyntaxError) as error:  # numpy parses the text itself
        raise ValueError(f"unknown dtype {payload.dtype[:20]!r}") from error
    if dtype.kind != "f" or len(payload.shape) != 2 or min(payload.shape) <= 0:
        raise ValueError(f"actions must be a non-empty 2-D float array, got {payload.shape}")
    if len(payload.data) != dtype.itemsize * payload.shape[0] * payload.shape[1]:
        raise ValueError("action bytes do not match dtype and shape")
    return np.frombuffer(payload.data, dtype=dtype).reshape(payload.shape).astype(np.float64)
