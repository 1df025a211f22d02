"""The chunk envelope (CONTRACT.md §1): wire structs, the normalized chunk, and its decoders.

Two doors lead in: a scenario or journal event (a JSON mapping, times in milliseconds) and a
wire frame (MessagePack, times in integer nanoseconds, actions as raw bytes with dtype and
shape). Both produce the same normalized :class:`Chunk` (times in ns on the sender's clock,
actions as a read-only float64 array) or a :class:`MalformedChunk`. Structural problems are
``MALFORMED``; a NaN or infinity is recorded per field and refused later as ``NONFINITE``, so
that one bad chunk is a result with reason codes, never an exception.

The client computes ``payload_hash`` itself over the canonical encoding of the identity fields
and the actions; whatever hash a server claims is not trusted.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import msgspec
import numpy as np

from assurance.clock import CLIENT_DOMAIN


class ReplacementPolicy(StrEnum):
    REPLACE = "replace"
    APPEND = "append"
    BLEND = "blend"


# ---------------------------------------------------------------------------------------------
# Wire structs (integer nanoseconds)
# ---------------------------------------------------------------------------------------------


class ArrayPayload(msgspec.Struct, frozen=True, kw_only=True):
    """A numeric array as raw bytes: decoding is one copy, not one object per number."""

    dtype: str
    shape: tuple[int, ...]
    data: bytes

    @classmethod
    def from_array(cls, array: np.ndarray) -> ArrayPayload:
        contiguous = np.ascontiguousarray(array)
        return cls(dtype=contiguous.dtype.str, shape=contiguous.shape, data=contiguous.tobytes())


class StateFingerprint(msgspec.Struct, frozen=True, kw_only=True):
    """The state a proposal assumed: the joint vector and a hash of it."""

    q: tuple[float, ...]
    hash: str = ""


class WireChunk(msgspec.Struct, frozen=True, kw_only=True):
    """A chunk on the wire. Optional fields are the ones a proposer may not know."""

    chunk_id: str
    sequence: int
    queue_epoch: int
    policy_checkpoint: str
    config_hash: str
    skill_version: str
    task_phase: str
    controller_mode: str
    calibration_epoch: int | str
    observation_id: str
    first_action_time: int
    action_dt: int
    actions: ArrayPayload
    skill: str | None = None
    observation_event_time: int | None = None
    observation_arrival_time: int | None = None
    clock_domain: str = CLIENT_DOMAIN
    inference_start: int | None = None
    inference_end: int | None = None
    server_send: int | None = None
    max_observation_age: int | None = None
    max_action_age: int | None = None
    state_fingerprint: StateFingerprint | None = None
    replacement_policy: ReplacementPolicy = ReplacementPolicy.REPLACE
    fallback_id: str | None = None
    phase_markers: tuple[int, ...] = ()
    action_units: str | None = None
    action_frame: str | None = None


# ---------------------------------------------------------------------------------------------
# The normalized chunk
# ---------------------------------------------------------------------------------------------

TIME_FIELDS = (
    "observation_event_time",
    "observation_arrival_time",
    "inference_start",
    "inference_end",
    "server_send",
    "first_action_time",
)
DURATION_FIELDS = ("action_dt", "max_observation_age", "max_action_age")


class Chunk(msgspec.Struct, frozen=True, kw_only=True, eq=False):
    """A structurally valid chunk. Times are ns in ``clock_domain``; ``None`` when absent or
    non-finite (the name of each non-finite field is in ``nonfinite``). A Struct rather than a
    dataclass because it is built once per arrival on the admission path (a C constructor)."""

    chunk_id: str
    sequence: int
    queue_epoch: int
    policy_checkpoint: str
    config_hash: str
    skill: str | None
    skill_version: str
    task_phase: str
    controller_mode: str
    calibration_epoch: str
    observation_id: str
    clock_domain: str
    client_receive: int
    times: dict[str, int | None]
    replacement_policy: ReplacementPolicy
    fallback_id: str | None
    phase_markers: tuple[int, ...]
    action_units: str | None
    action_frame: str | None
    fingerprint_q: tuple[float, ...] | None
    actions: Any
    """H x D float64, read-only (numpy; a Struct field holds any object)."""
    nonfinite: tuple[str, ...]
    payload_hash: str

    def time(self, name: str) -> int | None:
        return self.times.get(name)

    @property
    def horizon(self) -> int:
        return int(self.actions.shape[0])


@dataclass(frozen=True, slots=True)
class MalformedChunk:
    """A chunk that could not be decoded; ``chunk_id`` is kept when it could be read."""

    chunk_id: str | None
    detail: str


class ChunkDecodeError(Exception):
    """Inside the decoders only: why a chunk is MALFORMED (never escapes them)."""


# What numpy and msgspec may raise on hostile input that slipped past the explicit checks.
UNTRUSTED_INPUT_ERRORS = (ValueError, TypeError, OverflowError, SyntaxError)


# ---------------------------------------------------------------------------------------------
# Payload hash
# ---------------------------------------------------------------------------------------------

_hash_encoder = msgspec.msgpack.Encoder()


def payload_hash(
    identity: tuple[Any, ...], first_action_time: int | None, action_dt: int | None,
    actions: np.ndarray,
) -> str:
    """BLAKE2b-128 over the canonical encoding of identity fields, action timing and actions."""
    canonical = np.ascontiguousarray(actions, dtype="<f8")
    body = _hash_encoder.encode(
        [*identity, first_action_time, action_dt, list(canonical.shape), canonical.tobytes()]
    )
    return hashlib.blake2b(body, digest_size=16).hexdigest()


def identity_fields(fields: Mapping[str, Any]) -> tuple[Any, ...]:
    return tuple(
        fields[name]
        for name in (
            "chunk_id", "sequence", "queue_epoch", "policy_checkpoint", "config_hash",
            "skill_version", "task_phase", "controller_mode", "calibration_epoch",
            "observation_id",
        )
    )


REQUIRED_TEXT = (
    "policy_checkpoint", "config_hash", "skill_version", "task_phase", "controller_mode",
    "observation_id",
)
REQUIRED_INT = ("sequence", "queue_epoch")


def salvage_id(value: Any) -> str | None:
    if isinstance(value, str):
        return value
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    return None


def phase_markers_of(value: Any) -> tuple[int, ...]:
    if not isinstance(value, list | tuple) or not all(
        isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in value
    ):
        raise ChunkDecodeError("field 'phase_markers' must be a list of action indices")
    return tuple(value)


def is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def freeze_actions(actions: np.ndarray, nonfinite: list[str]) -> np.ndarray:
    if not np.isfinite(actions).all():
        nonfinite.append("actions")
    actions.setflags(write=False)
    return actions


# ---------------------------------------------------------------------------------------------
# Decoding a wire frame (nanoseconds)
# ---------------------------------------------------------------------------------------------

_wire_decoder = msgspec.msgpack.Decoder(WireChunk)
_loose_decoder = msgspec.msgpack.Decoder()
MAX_ACTION_BYTES = 1 << 20


MAX_TIME_NS = 10**19
"""Largest magnitude of a wire time or duration (10¹³ ms, as for scenario chunks)."""


def decode_wire_chunk(frame: bytes, client_receive: int) -> Chunk | MalformedChunk:
    """Decode a MessagePack chunk frame received at ``client_receive`` (client ns)."""
    try:
        wire = _wire_decoder.decode(frame)
    except (msgspec.ValidationError, msgspec.DecodeError) as error:
        return MalformedChunk(_salvage_wire_id(frame), short_error(error))
    try:
        return from_wire(wire, client_receive)
    except ChunkDecodeError as error:
        return MalformedChunk(wire.chunk_id, str(error))
    except UNTRUSTED_INPUT_ERRORS as error:
        return MalformedChunk(wire.chunk_id, f"undecodable: {type(error).__name__}")


def from_wire(wire: WireChunk, client_receive: int) -> Chunk:
    nonfinite: list[str] = []
    actions = freeze_actions(_array_from_payload(wire.actions), nonfinite)
    if wire.action_dt <= 0:
        raise ChunkDecodeError("action_dt must be positive")
    fields = {name: getattr(wire, name) for name in ("chunk_id", *REQUIRED_INT, *REQUIRED_TEXT)}
    fields["calibration_epoch"] = str(wire.calibration_epoch)
    if any(fields[name] == "" for name in ("chunk_id", *REQUIRED_TEXT)):
        raise ChunkDecodeError("an identity field is empty")
    phase_markers_of(list(wire.phase_markers))
    times = {name: getattr(wire, name) for name in (*TIME_FIELDS, *DURATION_FIELDS)}
    for name, value in times.items():
        if value is not None and abs(value) > MAX_TIME_NS:
            raise ChunkDecodeError(f"field {name!r} is out of range")
    fingerprint = wire.state_fingerprint.q if wire.state_fingerprint else None
    if fingerprint is not None and not all(math.isfinite(v) for v in fingerprint):
        nonfinite.append("state_fingerprint")
    return Chunk(
        **fields, skill=wire.skill, clock_domain=wire.clock_domain,
        client_receive=client_receive, times=times,
        replacement_policy=wire.replacement_policy, fallback_id=wire.fallback_id,
        phase_markers=wire.phase_markers, action_units=wire.action_units,
        action_frame=wire.action_frame, fingerprint_q=fingerprint, actions=actions,
        nonfinite=tuple(nonfinite),
        payload_hash=payload_hash(
            identity_fields(fields), wire.first_action_time, wire.action_dt, actions
        ),
    )


def _array_from_payload(payload: ArrayPayload) -> np.ndarray:
    try:
        dtype = np.dtype(payload.dtype)
    except (TypeError, ValueError, SyntaxError):  # numpy parses dtype text with its own parser
        raise ChunkDecodeError(f"actions have unknown dtype {payload.dtype!r}") from None
    if dtype.kind != "f" or len(payload.shape) != 2 or min(payload.shape, default=0) <= 0:
        raise ChunkDecodeError("actions must be a non-empty 2-D float array")
    if len(payload.data) > MAX_ACTION_BYTES:
        raise ChunkDecodeError("actions exceed the frame size limit")
    if len(payload.data) != dtype.itemsize * payload.shape[0] * payload.shape[1]:
        raise ChunkDecodeError("actions byte length does not match dtype and shape")
    flat = np.frombuffer(payload.data, dtype=dtype)
    return flat.reshape(payload.shape).astype(np.float64)


def _salvage_wire_id(frame: bytes) -> str | None:
    try:
        loose = _loose_decoder.decode(frame)
    except (msgspec.DecodeError, ValueError):
        return None
    return salvage_id(loose.get("chunk_id")) if isinstance(loose, dict) else None


def short_error(error: Exception) -> str:
    """An exception's text, cut to a log-friendly length."""
    text = str(error)
    return text if len(text) <= 160 else text[:157] + "..."


def to_wire(chunk: Chunk) -> WireChunk:
    """The wire form of a normalized chunk (used by the reference policy server and tests)."""
    times = {name: chunk.times.get(name) for name in (*TIME_FIELDS, *DURATION_FIELDS)}
    fingerprint = StateFingerprint(q=chunk.fingerprint_q) if chunk.fingerprint_q else None
    return WireChunk(
        chunk_id=chunk.chunk_id, sequence=chunk.sequence, queue_epoch=chunk.queue_epoch,
        policy_checkpoint=chunk.policy_checkpoint, config_hash=chunk.config_hash,
        skill=chunk.skill, skill_version=chunk.skill_version, task_phase=chunk.task_phase,
        controller_mode=chunk.controller_mode, calibration_epoch=chunk.calibration_epoch,
        observation_id=chunk.observation_id, clock_domain=chunk.clock_domain,
        actions=ArrayPayload.from_array(chunk.actions), state_fingerprint=fingerprint,
        replacement_policy=chunk.replacement_policy, fallback_id=chunk.fallback_id,
        phase_markers=chunk.phase_markers, action_units=chunk.action_units,
        action_frame=chunk.action_frame, **times,
    )
