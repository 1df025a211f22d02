"""The chunk envelope (docs/contract.md §1): wire structs, the normalized chunk, and its decoders.

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
from typing import Annotated, Any

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


MAX_TIME_NS = 2**63 - 1
"""Largest magnitude of a wire time or duration: the int64 range (about 292 years)."""

# Checked by the decoder itself (in C), so a hostile frame costs no Python per field.
WireText = Annotated[str, msgspec.Meta(min_length=1)]
WireTime = Annotated[int, msgspec.Meta(ge=-MAX_TIME_NS, le=MAX_TIME_NS)]
WireStep = Annotated[int, msgspec.Meta(gt=0, le=MAX_TIME_NS)]
WireCount = Annotated[int, msgspec.Meta(ge=0, le=MAX_TIME_NS)]
"""Sequence numbers and queue epochs: counted up from 0, never past the int64 range."""
ActionIndex = Annotated[int, msgspec.Meta(ge=0)]
RtcDelay = Annotated[int, msgspec.Meta(ge=0, le=1024)]
"""Actions of a chunk conditioned on the committed prefix (assurance/rtc.py, MAX_PREFIX_ROWS)."""


class WireChunk(msgspec.Struct, frozen=True, kw_only=True):
    """A chunk on the wire. Optional fields are the ones a proposer may not know."""

    chunk_id: WireText
    sequence: WireCount
    queue_epoch: WireCount
    policy_checkpoint: WireText
    config_hash: WireText
    skill_version: WireText
    task_phase: WireText
    controller_mode: WireText
    calibration_epoch: int | str
    observation_id: WireText
    first_action_time: WireTime
    action_dt: WireStep
    actions: ArrayPayload
    skill: str | None = None
    observation_event_time: WireTime | None = None
    observation_arrival_time: WireTime | None = None
    clock_domain: str = CLIENT_DOMAIN
    inference_start: WireTime | None = None
    inference_end: WireTime | None = None
    server_send: WireTime | None = None
    max_observation_age: WireTime | None = None
    max_action_age: WireTime | None = None
    state_fingerprint: StateFingerprint | None = None
    replacement_policy: ReplacementPolicy = ReplacementPolicy.REPLACE
    fallback_id: str | None = None
    phase_markers: tuple[ActionIndex, ...] = ()
    action_units: str | None = None
    action_frame: str | None = None
    rtc_delay: RtcDelay | None = None
    """Real-time chunking: the chunk's first action is due when the first action of the
    committed prefix its observation carried was, and its first ``rtc_delay`` actions
    reproduce that prefix."""


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
    rtc_delay: int | None = None

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
# What msgspec's decoder raises besides its own errors: UnicodeDecodeError (a ValueError) for
# invalid UTF-8, RecursionError for arrays nested deeper than the interpreter's stack allows.
UNDECODABLE_FRAME = (ValueError, RecursionError)


# ---------------------------------------------------------------------------------------------
# Payload hash
# ---------------------------------------------------------------------------------------------

_hash_encoder = msgspec.msgpack.Encoder()


def payload_hash(
    identity: tuple[Any, ...], first_action_time: int | None, action_dt: int | None,
    actions: np.ndarray,
) -> str:
    """SHA-256 (first 128 bits) over the canonical encoding of identity fields, action timing
    and actions."""
    canonical = np.ascontiguousarray(actions, dtype="<f8")
    return _digest(identity, first_action_time, action_dt, canonical.shape, canonical.tobytes())


def _digest(
    identity: tuple[Any, ...], first_action_time: int | None, action_dt: int | None,
    shape: tuple[int, ...], canonical: bytes,
) -> str:
    """The payload hash, given the actions already as little-endian float64 bytes.

    SHA-256 rather than BLAKE2b: it runs on every admitted chunk, and with the CPU's SHA
    instructions it costs a third of the instructions of this Python's BLAKE2b on 2.4 kB."""
    body = _hash_encoder.encode([*identity, first_action_time, action_dt, list(shape), canonical])
    return hashlib.sha256(body).hexdigest()[:32]


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
_CANONICAL = np.dtype("<f8")


def decode_wire_chunk(frame: bytes, client_receive: int) -> Chunk | MalformedChunk:
    """Decode a MessagePack chunk frame received at ``client_receive`` (client ns)."""
    try:
        wire = _wire_decoder.decode(frame)
    except (msgspec.ValidationError, msgspec.DecodeError) as error:
        return MalformedChunk(_salvage_wire_id(frame), short_error(error))
    except UNDECODABLE_FRAME as error:  # invalid UTF-8 in a string, arrays nested too deep
        return MalformedChunk(_salvage_wire_id(frame), f"undecodable: {type(error).__name__}")
    try:
        return from_wire(wire, client_receive)
    except ChunkDecodeError as error:
        return MalformedChunk(wire.chunk_id, str(error))
    except UNTRUSTED_INPUT_ERRORS as error:
        return MalformedChunk(wire.chunk_id, f"undecodable: {type(error).__name__}")


def from_wire(wire: WireChunk, client_receive: int) -> Chunk:
    """The normalized chunk of a decoded frame (field types and ranges were checked by the
    decoder; this is the admission path, so it builds the chunk in one go)."""
    actions, canonical = _actions_from_payload(wire.actions)
    finite = np.count_nonzero(np.isfinite(actions)) == actions.size
    nonfinite = () if finite else ("actions",)
    fingerprint = wire.state_fingerprint.q if wire.state_fingerprint else None
    if fingerprint is not None and not all(map(math.isfinite, fingerprint)):
        nonfinite += ("state_fingerprint",)
    calibration = str(wire.calibration_epoch)
    identity = (
        wire.chunk_id, wire.sequence, wire.queue_epoch, wire.policy_checkpoint, wire.config_hash,
        wire.skill_version, wire.task_phase, wire.controller_mode, calibration,
        wire.observation_id,
    )
    return Chunk(
        chunk_id=wire.chunk_id, sequence=wire.sequence, queue_epoch=wire.queue_epoch,
        policy_checkpoint=wire.policy_checkpoint, config_hash=wire.config_hash,
        skill=wire.skill, skill_version=wire.skill_version, task_phase=wire.task_phase,
        controller_mode=wire.controller_mode, calibration_epoch=calibration,
        observation_id=wire.observation_id, clock_domain=wire.clock_domain,
        client_receive=client_receive, times=_wire_times(wire),
        replacement_policy=wire.replacement_policy, fallback_id=wire.fallback_id,
        phase_markers=wire.phase_markers, action_units=wire.action_units,
        action_frame=wire.action_frame, fingerprint_q=fingerprint, actions=actions,
        nonfinite=nonfinite,
        payload_hash=_digest(
            identity, wire.first_action_time, wire.action_dt, actions.shape, canonical
        ),
        rtc_delay=wire.rtc_delay,
    )


def _wire_times(wire: WireChunk) -> dict[str, int | None]:
    """The times and durations of a frame, keyed (and ordered) as TIME_FIELDS, DURATION_FIELDS."""
    return {
        "observation_event_time": wire.observation_event_time,
        "observation_arrival_time": wire.observation_arrival_time,
        "inference_start": wire.inference_start, "inference_end": wire.inference_end,
        "server_send": wire.server_send, "first_action_time": wire.first_action_time,
        "action_dt": wire.action_dt, "max_observation_age": wire.max_observation_age,
        "max_action_age": wire.max_action_age,
    }


def _actions_from_payload(payload: ArrayPayload) -> tuple[np.ndarray, bytes]:
    """The actions as a read-only float64 array, and their canonical (little-endian float64)
    bytes. The common dtype is viewed in place: the frame's bytes are immutable already."""
    dtype = _CANONICAL if payload.dtype == "<f8" else _dtype_of(payload.dtype)
    shape, data = payload.shape, payload.data
    if dtype.kind != "f" or len(shape) != 2 or min(shape, default=0) <= 0:
        raise ChunkDecodeError("actions must be a non-empty 2-D float array")
    if len(data) > MAX_ACTION_BYTES:
        raise ChunkDecodeError("actions exceed the frame size limit")
    if len(data) != dtype.itemsize * shape[0] * shape[1]:
        raise ChunkDecodeError("actions byte length does not match dtype and shape")
    flat = np.frombuffer(data, dtype=dtype)
    if dtype is _CANONICAL:
        return flat.reshape(shape), data
    actions = flat.reshape(shape).astype(np.float64)
    actions.setflags(write=False)
    return actions, actions.astype(_CANONICAL, copy=False).tobytes()


def _dtype_of(text: str) -> np.dtype:
    try:
        return np.dtype(text)
    except (TypeError, ValueError, SyntaxError):  # numpy parses dtype text with its own parser
        raise ChunkDecodeError(f"actions have unknown dtype {text!r}") from None


def _salvage_wire_id(frame: bytes) -> str | None:
    try:
        loose = _loose_decoder.decode(frame)
    except (msgspec.DecodeError, *UNDECODABLE_FRAME):
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
        action_frame=chunk.action_frame, rtc_delay=chunk.rtc_delay, **times,
    )
