"""The server's side of the policy-link wire protocol, written from ``docs/protocol.md``.

This is an independent peer of warden's own codec (``kernel/wire.py``): it shares no code with
it, only the document, so that a mistake in one side's codec shows up as a disagreement in the
cross-check tests (``tests/wire/test_peer_codec.py``) instead of being copied into its test
peer. Every websocket message is one binary frame holding ``[type, body]``: a MessagePack array
of the type name and the body, a MessagePack map inlined in the array (not wrapped in ``bin``).
The body stays undecoded until the type is known, so a broken body is still attributable.
"""

from __future__ import annotations

import math
from enum import StrEnum
from typing import Annotated

import msgspec
import numpy as np

from peer.handshake import ClientHello, HandshakeDecision, HandshakeOffer

PROTOCOL_RANGE: tuple[int, int] = (1, 3)
"""The wire versions this server speaks; version 2 adds ``clock_report``, version 3 camera
frames in observations."""
IMAGE_VERSION = 3
MAX_FRAME_BYTES = 1 << 20
"""The transport refuses larger frames (websocket close 1009), on both sides."""
SERVER_CLOCK_DOMAIN = "server"
"""The ``clock_domain`` of every time this server writes."""

INT64_MAX = 2**63 - 1
Time = Annotated[int, msgspec.Meta(ge=-INT64_MAX, le=INT64_MAX)]
"""A time or duration in ns: ``|t| <= 2**63 - 1``."""
Count = Annotated[int, msgspec.Meta(ge=0, le=INT64_MAX)]
"""A sequence number or a queue epoch: ``0 <= n <= 2**63 - 1``."""
Offset = Annotated[int, msgspec.Meta(ge=-(2**62), le=2**62)]
"""A measured clock offset: ``|offset| <= 2**62``."""
Duration = Annotated[int, msgspec.Meta(ge=0, le=INT64_MAX)]


class MessageType(StrEnum):
    HELLO = "hello"
    OFFER = "offer"
    DECISION = "decision"
    CLOCK_PING = "clock_ping"
    CLOCK_PONG = "clock_pong"
    CLOCK_REPORT = "clock_report"
    OBSERVATION = "observation"
    CHUNK = "chunk"
    HEARTBEAT = "heartbeat"
    BYE = "bye"


MIN_VERSION: dict[MessageType, int] = {MessageType.CLOCK_REPORT: 2}
"""Message types that exist only from a wire version on (every other type: version 1)."""


class ByeReason(StrEnum):
    SHUTDOWN = "shutdown"
    PROTOCOL_VIOLATION = "protocol_violation"
    UNSUPPORTED_VERSION = "unsupported_version"
    HANDSHAKE_REJECTED = "handshake_rejected"
    HANDSHAKE_TIMEOUT = "handshake_timeout"
    FINGERPRINT_MISMATCH = "fingerprint_mismatch"
    HEARTBEAT_TIMEOUT = "heartbeat_timeout"
    CLOCK_TIMEOUT = "clock_timeout"
    SESSION_ENDED = "session_ended"
    FAULT_INJECTED = "fault_injected"


class ProtocolViolation(Exception):
    """The client broke the protocol: the server says ``bye`` with ``reason`` and closes."""

    def __init__(self, detail: str, reason: ByeReason = ByeReason.PROTOCOL_VIOLATION) -> None:
        super().__init__(detail)
        self.reason = reason
        self.detail = detail


# -- bodies ------------------------------------------------------------------------------------


class Frame(msgspec.Struct, frozen=True, array_like=True):
    """``[type, body]``: the one layout every frame has."""

    type: str
    body: msgspec.Raw


class ArrayPayload(msgspec.Struct, frozen=True, kw_only=True):
    """A numeric array: a NumPy type string (``<f8``), its shape and its raw bytes (row-major)."""

    dtype: str
    shape: tuple[int, ...]
    data: bytes


class Hello(msgspec.Struct, frozen=True, kw_only=True):
    client_id: str
    protocol: tuple[int, int]
    hello: ClientHello


class Offer(msgspec.Struct, frozen=True, kw_only=True):
    server_id: str
    offer: HandshakeOffer


class Decision(msgspec.Struct, frozen=True, kw_only=True):
    decision: HandshakeDecision
    queue_epoch: Count


class ClockPing(msgspec.Struct, frozen=True, kw_only=True):
    seq: Count
    t0: Time


class ClockPong(msgspec.Struct, frozen=True, kw_only=True):
    seq: Count
    t0: Time
    t_server: Time


class ClockReport(msgspec.Struct, frozen=True, kw_only=True):
    offset: Offset
    round_trip: Duration


PrefixLength = Annotated[int, msgspec.Meta(ge=0, le=1024)]


class Prefix(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Real-time chunking: what the robot committed from the action in force at the
    observation's time on (rows × action_dim, due at ``first_action_time + k * action_dt``),
    the inference delay and the execution horizon in actions. Sent only to a server that
    offered it."""

    actions: ArrayPayload
    first_action_time: Time
    """Client clock: when ``actions[0]`` was due."""
    action_dt: Annotated[int, msgspec.Meta(gt=0, le=INT64_MAX)]
    delay: PrefixLength
    horizon: PrefixLength


Side = Annotated[int, msgspec.Meta(ge=1, le=4096)]
Label = Annotated[str, msgspec.Meta(min_length=1, max_length=64)]


class Image(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """A camera frame (version 3): ``raw`` RGB bytes, row-major, or a ``jpeg`` file."""

    camera: Label
    encoding: Annotated[str, msgspec.Meta(pattern="^(raw|jpeg)$")]
    height: Side
    width: Side
    data: bytes
    t_capture: Time
    digest: Label
    calibration_epoch: Label


class Observation(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Only what a robot measures: an unknown field (a goal, a target) is a violation."""

    observation_id: str
    t_event: Time
    queue_epoch: Count
    task_phase: str
    q: ArrayPayload
    qd: ArrayPayload | None = None
    wrench: ArrayPayload | None = None
    gripper: float | None = None
    rtc: Prefix | None = None
    images: Annotated[tuple[Image, ...], msgspec.Meta(max_length=8)] = ()
    t_state: Time | None = None
    """Version 3, with frames: when the joints were read (``t_event`` is the oldest frame's)."""


class Heartbeat(msgspec.Struct, frozen=True, kw_only=True):
    seq: Count
    t_send: Time


class Bye(msgspec.Struct, frozen=True, kw_only=True):
    reason: ByeReason
    detail: str = ""


Message = (
    Hello | Offer | Decision | ClockPing | ClockPong | ClockReport | Observation | Heartbeat | Bye
)
BODY_TYPES: dict[MessageType, type[Message]] = {
    MessageType.HELLO: Hello, MessageType.OFFER: Offer, MessageType.DECISION: Decision,
    MessageType.CLOCK_PING: ClockPing, MessageType.CLOCK_PONG: ClockPong,
    MessageType.CLOCK_REPORT: ClockReport, MessageType.OBSERVATION: Observation,
    MessageType.HEARTBEAT: Heartbeat, MessageType.BYE: Bye,
}
"""Every type but ``chunk``, whose body is the envelope (``envelope.py``)."""
_KIND_OF = {body: kind for kind, body in BODY_TYPES.items()}
_BODY_DECODERS = {kind: msgspec.msgpack.Decoder(body) for kind, body in BODY_TYPES.items()}
_FRAME_DECODER = msgspec.msgpack.Decoder(Frame)
_ENCODER = msgspec.msgpack.Encoder()


# -- encoding ----------------------------------------------------------------------------------


def encode(message: Message) -> bytes:
    """The frame of one message."""
    return encode_raw(_KIND_OF[type(message)], _ENCODER.encode(message))


def encode_raw(kind: str, body: bytes) -> bytes:
    """A frame around a body already encoded (one MessagePack object), of any type name."""
    return _ENCODER.encode(Frame(kind, msgspec.Raw(body)))


def array_payload(values: np.ndarray, dtype: str = "<f8") -> ArrayPayload:
    """An array as ``dtype`` bytes in row-major order (``<f8``: little-endian float64)."""
    array = np.ascontiguousarray(values, dtype=dtype)
    return ArrayPayload(dtype=array.dtype.str, shape=array.shape, data=array.tobytes())


# -- decoding ----------------------------------------------------------------------------------


def decode_frame(data: bytes | str) -> Frame:
    """The ``[type, body]`` of one websocket message.

    Raises:
        ProtocolViolation: a text frame, or bytes that are not a two-element array.
    """
    if isinstance(data, str):
        raise ProtocolViolation("text frame on a binary protocol")
    try:
        return _FRAME_DECODER.decode(data)
    except (msgspec.DecodeError, ValueError, RecursionError) as error:
        raise ProtocolViolation(f"not a [type, body] frame: {_short(error)}") from error


def message_type(frame: Frame, version: int | None = None) -> MessageType:
    """The frame's type, checked against the agreed wire version (None: not agreed yet).

    Raises:
        ProtocolViolation: an unknown type, or one newer than the agreed version.
    """
    try:
        kind = MessageType(frame.type)
    except ValueError as error:
        raise ProtocolViolation(f"unknown message type {frame.type[:40]!r}") from error
    needed = MIN_VERSION.get(kind, 1)
    if version is not None and version < needed:
        raise ProtocolViolation(f"{kind} needs wire version {needed}, agreed {version}")
    return kind


def decode_body(frame: Frame, kind: MessageType) -> Message:
    """The typed body of a frame of any type but ``chunk``.

    Raises:
        ProtocolViolation: a ``chunk`` frame, or a body that is not the type's struct.
    """
    decoder = _BODY_DECODERS.get(kind)
    if decoder is None:
        raise ProtocolViolation(f"{kind} bodies are decoded as chunk envelopes")
    try:
        return decoder.decode(frame.body)
    except (msgspec.DecodeError, ValueError, RecursionError) as error:
        raise ProtocolViolation(f"bad {kind} body: {_short(error)}") from error


def payload_vector(payload: ArrayPayload, length: int) -> np.ndarray:
    """A state vector as float64: one dimension of ``length`` floats of any float dtype.

    Raises:
        ProtocolViolation: another dtype, shape or length, or bytes that do not fill it.
    """
    dtype = _float_dtype(payload)
    if dtype is None or payload.shape != (length,):
        raise ProtocolViolation(
            f"a state vector is {length} floats, got {payload.dtype[:20]} {payload.shape[:4]}")
    return _floats(payload, dtype, "vector")


def payload_rows(payload: ArrayPayload, width: int, most: int) -> np.ndarray:
    """Rows of ``width`` floats (at most ``most`` of them) as float64.

    Raises:
        ProtocolViolation: another dtype or shape, or bytes that do not fill it.
    """
    dtype, shape = _float_dtype(payload), payload.shape
    if dtype is None or len(shape) != 2 or shape[1] != width or not 0 <= shape[0] <= most:
        raise ProtocolViolation(f"expected up to {most} rows of {width} floats, got "
                                f"{payload.dtype[:20]} {shape[:4]}")
    return _floats(payload, dtype, "array")


def _float_dtype(payload: ArrayPayload) -> np.dtype | None:
    """The payload's dtype if it is a float one, else None.

    Raises:
        ProtocolViolation: numpy cannot read the dtype text.
    """
    try:
        dtype = np.dtype(payload.dtype)
    except (TypeError, ValueError, SyntaxError) as error:  # numpy parses the text itself
        raise ProtocolViolation(f"unknown dtype {payload.dtype[:20]!r}") from error
    return dtype if dtype.kind == "f" else None


def _floats(payload: ArrayPayload, dtype: np.dtype, what: str) -> np.ndarray:
    """The payload's values as float64 in its (checked) shape.

    Raises:
        ProtocolViolation: the bytes do not fill that shape exactly.
    """
    if len(payload.data) != dtype.itemsize * math.prod(payload.shape):
        raise ProtocolViolation(f"{what} bytes do not match dtype and shape")
    return np.frombuffer(payload.data, dtype=dtype).astype(np.float64).reshape(payload.shape)


def _short(error: Exception) -> str:
    text = str(error)
    return text if len(text) <= 160 else text[:157] + "..."
