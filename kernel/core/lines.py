"""Decision-log lines (docs/contract.md §7) as frozen msgspec Structs, one kind per class.

Field order is fixed by the class, ``kind`` comes first, and optional fields are omitted when
unset, so the same decisions always encode to the same bytes. ``t`` is in milliseconds.
"""

from __future__ import annotations

from enum import StrEnum

import msgspec

from assurance.fallback import FallbackCommand, Mode, Owner
from assurance.handshake import HandshakeVerdict
from assurance.reasons import ReasonCode
from skills.phases import TaskPhase

Ms = int | float


class Decision(StrEnum):
    """What admission decided on a chunk (docs/contract.md §4)."""

    ACCEPTED = "accepted"
    TRIMMED = "trimmed"
    REPLACED = "replaced"
    BLENDED = "blended"
    REJECTED = "rejected"
    IGNORED = "ignored"


ADMITTED = frozenset({Decision.ACCEPTED, Decision.TRIMMED, Decision.REPLACED,
                      Decision.BLENDED})


class Machine(StrEnum):
    TASK = "task"
    FALLBACK = "fallback"


class QueueAction(StrEnum):
    """A queue line's action (the queue's own changes, not a fallback's queue rule)."""

    PURGE = "purge"
    NEW_EPOCH = "new_epoch"
    EXPIRE = "expire"


class MotionRequest(StrEnum):
    MOVE = "move"
    GRIPPER = "gripper"
    INSERT = "insert"
    RETREAT = "retreat"


class MotionDecision(StrEnum):
    PLANNED = "planned"
    SET = "set"
    STARTED = "started"
    REFUSED = "refused"


class SentRef(msgspec.Struct, frozen=True):
    chunk_id: str
    index: int


class CollisionLine(msgspec.Struct, frozen=True, kw_only=True):
    """Where a refused chunk's motion breaks a clearance (COLLISION): the pair of solids, the
    action the motion goes to, the pair's distance there, the lower bound on its distance
    over the motion into it, and the clearance it must keep (m)."""

    pair: tuple[str, str]
    action: int
    distance: float
    bound: float
    needed: float


class ChunkLine(msgspec.Struct, frozen=True, kw_only=True, tag_field="kind", tag="chunk",
                omit_defaults=True):
    t: Ms
    chunk_id: str | None
    decision: Decision
    reasons: tuple[ReasonCode, ...]
    queue_epoch: int
    queue_depth: int
    trimmed: int | None = None
    projection_distance: float | None = None
    merge: str | None = None
    displaced: int | None = None
    observation_age_ms: Ms | None = None
    divergence: float | None = None
    detail: str | None = None
    collision: CollisionLine | None = None


class TickLine(msgspec.Struct, frozen=True, kw_only=True, tag_field="kind", tag="tick",
               omit_defaults=True):
    t: Ms
    command: FallbackCommand
    owner: Owner
    sent: SentRef | None
    phase: TaskPhase
    mode: Mode
    reason: ReasonCode | None = None
    age_ms: Ms | None = None


class TransitionLine(msgspec.Struct, frozen=True, kw_only=True, tag_field="kind",
                     tag="transition", omit_defaults=True):
    t: Ms
    machine: Machine
    # A task phase or a fallback mode, as ``machine`` says: both are string enums, and a
    # msgspec union may hold only one of those.
    from_: str = msgspec.field(name="from")
    to: str
    trigger: ReasonCode
    accepted: bool = True
    requested: str | None = None
    reasons: tuple[ReasonCode, ...] = ()
    missing_evidence: tuple[str, ...] = ()
    owner: str | None = None
    command: str | None = None
    queue: str | None = None
    recovery: str | None = None
    detail: str | None = None


class HandshakeLine(msgspec.Struct, frozen=True, kw_only=True, tag_field="kind",
                    tag="handshake", omit_defaults=True):
    t: Ms
    decision: HandshakeVerdict
    fingerprint: str | None = None
    reasons: tuple[ReasonCode, ...] = ()
    protocol: int | None = None
    queue_epoch: int | None = None


class QueueLine(msgspec.Struct, frozen=True, kw_only=True, tag_field="kind", tag="queue",
                omit_defaults=True):
    t: Ms
    action: QueueAction
    queue_epoch: int
    dropped: int = 0
    chunk_id: str | None = None
    reason: ReasonCode | None = None


class RequestLine(msgspec.Struct, frozen=True, kw_only=True, tag_field="kind", tag="request",
                  omit_defaults=True):
    t: Ms
    observation_id: str | None
    queue_depth: int
    depth_ms: Ms = 0
    low_watermark_ms: Ms = 0


class MotionLine(msgspec.Struct, frozen=True, kw_only=True, tag_field="kind", tag="motion",
                 omit_defaults=True):
    """What the core did with a task's motion request: a classical move (``move``, planned or
    refused when the planner takes it up), the gripper's opening (``gripper``), the contact
    owner's descent (``insert``)."""

    t: Ms
    request: MotionRequest
    decision: MotionDecision
    move_id: int | None = None
    duration_ms: Ms | None = None
    opening: float | None = None
    detail: str | None = None


class CameraLine(msgspec.Struct, frozen=True, kw_only=True, tag_field="kind", tag="camera",
                 omit_defaults=True):
    """A camera was lost, froze or came back, and what losing it means (``on_loss``;
    ``grace_ms`` for ``continue``)."""

    t: Ms
    camera: str
    status: str
    on_loss: str
    grace_ms: Ms | None = None
    detail: str | None = None


Line = (ChunkLine | TickLine | TransitionLine | HandshakeLine | QueueLine | RequestLine
        | MotionLine | CameraLine)

_encoder = msgspec.json.Encoder()


def encode(line: Line) -> bytes:
    return _encoder.encode(line)


LINE_TYPES: dict[str, type[Line]] = {
    "chunk": ChunkLine, "tick": TickLine, "transition": TransitionLine,
    "handshake": HandshakeLine, "queue": QueueLine, "request": RequestLine,
    "motion": MotionLine,
}
decoder = msgspec.json.Decoder(Line)
