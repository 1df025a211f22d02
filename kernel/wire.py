"""The policy-link wire protocol: websocket binary frames, msgspec MessagePack, versioned.

Every websocket message is one binary frame holding a two-field envelope, :class:`Frame`
(``[type, body]``). The envelope is decoded first and the body in a second step, so a frame whose
body is broken is still attributable: a broken ``chunk`` body becomes a ``MALFORMED`` refusal in
the core (``assurance.envelope.decode_wire_chunk`` decodes it, so the core sees exactly what
arrived), while a frame that is not even an envelope is a protocol violation that closes the
connection. No pickle, no code objects: every body is a frozen msgspec Struct of plain fields,
numeric arrays travel as raw bytes with dtype and shape (:class:`ArrayPayload`), and every time is
an integer number of nanoseconds.

Versions: protocol 1 is the base set of messages; protocol 2 adds :class:`ClockReport`, by which
the client tells the server the clock offset it measured, so the server can state observation
times in its own clock; protocol 3 adds camera frames to observations (:class:`WireImage`).
The version in use is the one the handshake agreed.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Annotated

import msgspec
import numpy as np

from assurance.envelope import (
    MAX_TIME_NS,
    UNDECODABLE_FRAME,
    ArrayPayload,
    WireChunk,
    WireCount,
    WireStep,
    WireTime,
    short_error,
)
from assurance.handshake import ClientHello, HandshakeDecision, HandshakeOffer
from assurance.rtc import PrefixLength, RtcPrefix

PROTOCOL_RANGE: tuple[int, int] = (1, 3)
IMAGE_PROTOCOL = 3
"""The first version whose observations carry camera frames."""
MAX_FRAME_BYTES = 1 << 20
"""The protocol's ceiling on a chunk frame; a client may configure a lower limit (the
manifest's ``policy.max_frame_bytes``). Larger frames are refused by the transport (close
1009). An observation with frames may be larger: a server sizes its own limit from its cameras
(docs/protocol.md, "Camera frames")."""
MAX_IMAGES = 8
MAX_IMAGE_SIDE = 4096
SERVER_CLOCK_DOMAIN = "server"
"""The ``clock_domain`` of the server's times, and the domain of the client's clock sync."""
MAX_CLOCK_OFFSET_NS = 2**62
"""Largest clock offset a sync may measure (about 146 years): two hosts' clocks, even a
boot-relative one against the Unix epoch, are far closer. A pong implying more is a violation,
so an offset always fits a 64-bit integer with room to add any wire time's magnitude."""

# Bounded in the decoder (in C), so no value a peer sends can overflow what is computed from it.
ClockOffset = Annotated[int, msgspec.Meta(ge=-MAX_CLOCK_OFFSET_NS, le=MAX_CLOCK_OFFSET_NS)]
Duration = Annotated[int, msgspec.Meta(ge=0, le=MAX_TIME_NS)]


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


class ByeReason(StrEnum):
    """Why a side ends a connection; sent in :class:`Bye` and used as the close reason."""

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
    """The peer broke the protocol; the connection is closed with a :class:`Bye`."""

    def __init__(self, detail: str, reason: ByeReason = ByeReason.PROTOCOL_VIOLATION) -> None:
        super().__init__(detail)
        self.reason = reason
        self.detail = detail


# ---------------------------------------------------------------------------------------------
# Messages
# ---------------------------------------------------------------------------------------------


class Frame(msgspec.Struct, frozen=True, array_like=True):
    """The envelope: the body stays undecoded (Raw) until its type is known."""

    type: str
    body: msgspec.Raw


class Hello(msgspec.Struct, frozen=True, kw_only=True):
    """Client → server, first message: who I am, which wire versions, my handshake side."""

    client_id: str
    protocol: tuple[int, int]
    hello: ClientHello


class Offer(msgspec.Struct, frozen=True, kw_only=True):
    """Server → client: the server's side of the compatibility handshake."""

    server_id: str
    offer: HandshakeOffer


class Decision(msgspec.Struct, frozen=True, kw_only=True):
    """Client → server: the core's decision. Only ``ACCEPT`` opens the session.

    ``queue_epoch`` is the client's epoch once the decision took effect (an accepted handshake
    may start a new one); observations carry the epoch they belong to anyway.
    """

    decision: HandshakeDecision
    queue_epoch: WireCount


class ClockPing(msgspec.Struct, frozen=True, kw_only=True):
    seq: WireCount
    t0: WireTime
    """Client clock at sending."""


class ClockPong(msgspec.Struct, frozen=True, kw_only=True):
    seq: WireCount
    t0: WireTime
    t_server: WireTime
    """Server clock when the ping was answered."""


class ClockReport(msgspec.Struct, frozen=True, kw_only=True):
    """Client → server (protocol 2): ``t_client = t_server + offset``, known to ±round_trip/2."""

    offset: ClockOffset
    round_trip: Duration


class WirePrefix(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The committed prefix on the wire: ``actions`` (rows × the chunks' width, float64) due at
    ``first_action_time + k * action_dt``, from the one in force at the observation's
    ``t_event`` on; ``delay`` and ``horizon`` in actions (assurance/rtc.py)."""

    actions: ArrayPayload
    first_action_time: WireTime
    """Client clock: when ``actions[0]`` was due (the action in force at ``t_event``)."""
    action_dt: WireStep
    delay: PrefixLength
    horizon: PrefixLength


class ImageEncoding(StrEnum):
    RAW = "raw"
    """``uint8`` RGB, ``height × width × 3`` bytes, row-major."""
    JPEG = "jpeg"
    """A JPEG file's bytes (baseline, RGB)."""


class WireImage(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """One camera frame in an observation (protocol 3): the pixels, when and under which
    calibration they were taken, and the digest of the raw RGB image (``sha256`` over its shape
    and bytes, first 128 bits: what the journal keeps)."""

    camera: Annotated[str, msgspec.Meta(min_length=1, max_length=64)]
    encoding: ImageEncoding
    height: Annotated[int, msgspec.Meta(ge=1, le=MAX_IMAGE_SIDE)]
    width: Annotated[int, msgspec.Meta(ge=1, le=MAX_IMAGE_SIDE)]
    data: bytes
    t_capture: WireTime
    """Client clock when the frame was taken."""
    digest: Annotated[str, msgspec.Meta(min_length=1, max_length=64)]
    calibration_epoch: Annotated[str, msgspec.Meta(min_length=1, max_length=64)]


class Observation(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """What a real robot sends: its own measurements and the context it is in, nothing more.

    Unknown fields are refused, so nothing the robot does not measure (a goal, a target pose)
    can be smuggled to the policy.
    """

    observation_id: str
    t_event: WireTime
    """Client clock when the observation was captured."""
    queue_epoch: WireCount
    task_phase: str
    q: ArrayPayload
    qd: ArrayPayload | None = None
    wrench: ArrayPayload | None = None
    gripper: float | None = None
    rtc: WirePrefix | None = None
    """Real-time chunking, to a server that offered it: what warden committed from
    ``t_event`` on (assurance/rtc.py)."""
    images: Annotated[tuple[WireImage, ...], msgspec.Meta(max_length=MAX_IMAGES)] = ()
    """Protocol 3: the cameras' frames, one per camera of the session's observation keys;
    ``t_event`` is then no later than the oldest ``t_capture``."""
    t_state: WireTime | None = None
    """Protocol 3, with frames: when ``q``, ``qd``, ``wrench`` and ``gripper`` were measured
    (the last control tick's sample); a policy extrapolates the joints from here, and counts
    the observation's age from ``t_event``, its oldest frame's time."""


class Heartbeat(msgspec.Struct, frozen=True, kw_only=True):
    seq: WireCount
    t_send: WireTime


class Bye(msgspec.Struct, frozen=True, kw_only=True):
    reason: str
    detail: str = ""


Message = (
    Hello | Offer | Decision | ClockPing | ClockPong | ClockReport | Observation | Heartbeat | Bye
)

_TYPES: dict[type, MessageType] = {
    Hello: MessageType.HELLO, Offer: MessageType.OFFER, Decision: MessageType.DECISION,
    ClockPing: MessageType.CLOCK_PING, ClockPong: MessageType.CLOCK_PONG,
    ClockReport: MessageType.CLOCK_REPORT, Observation: MessageType.OBSERVATION,
    Heartbeat: MessageType.HEARTBEAT, Bye: MessageType.BYE,
}
_DECODERS = {kind: msgspec.msgpack.Decoder(cls) for cls, kind in _TYPES.items()}
MIN_VERSION: dict[MessageType, int] = {MessageType.CLOCK_REPORT: 2}
"""Messages that exist only from a protocol version on (all others: version 1)."""

_encoder = msgspec.msgpack.Encoder()
_frame_decoder = msgspec.msgpack.Decoder(Frame)


# ---------------------------------------------------------------------------------------------
# Encoding and decoding
# ---------------------------------------------------------------------------------------------


def encode(message: Message) -> bytes:
    return _encoder.encode(Frame(_TYPES[type(message)], msgspec.Raw(_encoder.encode(message))))


def encode_chunk(chunk: WireChunk) -> bytes:
    return encode_chunk_body(_encoder.encode(chunk))


def encode_chunk_body(body: bytes) -> bytes:
    """A chunk frame around an already-encoded body (must be one MessagePack object)."""
    return encode_raw(MessageType.CHUNK, body)


def encode_raw(kind: str, body: bytes) -> bytes:
    return _encoder.encode(Frame(kind, msgspec.Raw(body)))


def decode_frame(data: bytes | str) -> Frame:
    """The envelope of one websocket message; anything else is a protocol violation."""
    if not isinstance(data, bytes | bytearray | memoryview):
        raise ProtocolViolation("text frame on a binary protocol")
    try:
        return _frame_decoder.decode(data)
    except (msgspec.DecodeError, *UNDECODABLE_FRAME) as error:  # invalid UTF-8, deep nesting
        raise ProtocolViolation(f"undecodable frame: {_why(error)}") from error


def message_type(frame: Frame, version: int | None = None) -> MessageType:
    """The frame's type; unknown types (or types newer than ``version``) are violations."""
    try:
        kind = MessageType(frame.type)
    except ValueError as error:
        raise ProtocolViolation(f"unknown message type {frame.type[:40]!r}") from error
    if version is not None and version < MIN_VERSION.get(kind, 1):
        raise ProtocolViolation(f"{kind} needs protocol {MIN_VERSION[kind]}, agreed {version}")
    return kind


def decode_body(frame: Frame, kind: MessageType) -> Message:
    """The typed body of a non-chunk frame (chunk bodies go to ``decode_wire_chunk``)."""
    decoder = _DECODERS.get(kind)
    if decoder is None:
        raise ProtocolViolation(f"{kind} has no message body decoder")
    try:
        return decoder.decode(frame.body)
    except (msgspec.DecodeError, *UNDECODABLE_FRAME) as error:
        raise ProtocolViolation(f"bad {kind} body: {_why(error)}") from error


def _why(error: Exception) -> str:
    if isinstance(error, msgspec.DecodeError):  # a ValidationError is one too
        return short_error(error)
    return type(error).__name__


# ---------------------------------------------------------------------------------------------
# Arrays and clocks
# ---------------------------------------------------------------------------------------------


def image_payload(camera: str, encoding: ImageEncoding, image: np.ndarray, data: bytes,
                  t_capture: int, digest: str, calibration_epoch: str) -> WireImage:
    """One frame as an observation carries it (``data``: ``image``'s bytes, raw or JPEG)."""
    height, width = image.shape[:2]
    return WireImage(camera=camera, encoding=encoding, height=height, width=width, data=data,
                     t_capture=t_capture, digest=digest, calibration_epoch=calibration_epoch)


def prefix_payload(prefix: RtcPrefix) -> WirePrefix:
    """The committed prefix as an observation carries it."""
    actions = np.array(prefix.actions, dtype="<f8")
    return WirePrefix(actions=ArrayPayload.from_array(actions),
                      first_action_time=prefix.first_due, action_dt=prefix.action_dt,
                      delay=prefix.delay, horizon=prefix.horizon)


def vector_payload(values: np.ndarray | tuple[float, ...]) -> ArrayPayload:
    return ArrayPayload.from_array(np.asarray(values, dtype="<f8").reshape(-1))


def optional_payload(values: np.ndarray | None) -> ArrayPayload | None:
    return None if values is None else vector_payload(values)


def payload_vector(payload: ArrayPayload, length: int | None = None) -> np.ndarray:
    """A 1-D float64 vector from a payload; a wrong dtype, shape or size is a violation."""
    try:
        dtype = np.dtype(payload.dtype)
    except (TypeError, ValueError, SyntaxError) as error:  # numpy parses dtype text itself
        raise ProtocolViolation(f"unknown dtype {payload.dtype!r}") from error
    if dtype.kind != "f" or len(payload.shape) != 1:
        raise ProtocolViolation("a state vector must be a 1-D float array")
    if len(payload.data) != dtype.itemsize * payload.shape[0]:
        raise ProtocolViolation("vector byte length does not match dtype and shape")
    if length is not None and payload.shape[0] != length:
        raise ProtocolViolation(f"vector has {payload.shape[0]} values, expected {length}")
    return np.frombuffer(payload.data, dtype=dtype).astype(np.float64)


@dataclass(frozen=True, slots=True)
class ClockSample:
    """One ping/pong: ``offset = midpoint - t_server`` (so ``t_client = t_server + offset``)."""

    t0: int
    t_server: int
    t1: int

    @property
    def round_trip(self) -> int:
        return self.t1 - self.t0

    @property
    def offset(self) -> int:
        return (self.t0 + self.t1) // 2 - self.t_server


def clock_sample(t0: int, pong: ClockPong, t1: int) -> ClockSample:
    """The sample of the ping sent at ``t0`` and answered by ``pong`` at ``t1``.

    Raises:
        ProtocolViolation: the pong does not echo the ping's ``t0``, or its ``t_server`` puts
            the two clocks more than :data:`MAX_CLOCK_OFFSET_NS` apart.
    """
    if pong.t0 != t0:
        raise ProtocolViolation(f"clock pong {pong.seq} echoes t0 {pong.t0}, the ping sent {t0}")
    sample = ClockSample(t0=t0, t_server=pong.t_server, t1=t1)
    if abs(sample.offset) > MAX_CLOCK_OFFSET_NS:
        raise ProtocolViolation(f"clock pong {pong.seq}: t_server {pong.t_server} is not a "
                                "plausible clock reading")
    return sample


def best_sample(samples: list[ClockSample]) -> ClockSample | None:
    """The minimum round-trip sample: the one whose offset is known most tightly."""
    valid = [s for s in samples if s.round_trip >= 0]
    return min(valid, key=lambda s: s.round_trip) if valid else None
