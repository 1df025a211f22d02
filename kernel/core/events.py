"""Events the core consumes: frozen msgspec Structs, times in client nanoseconds.

The shell turns I/O into these; a scenario or journal is a list of them. A chunk event carries
the already-decoded envelope (:class:`~assurance.envelope.Chunk` or
:class:`~assurance.envelope.MalformedChunk`): decoding is the first admission gate, and the
same decoded chunk is what the journal records.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any

import msgspec

from assurance.envelope import Chunk, MalformedChunk
from assurance.handshake import OfferIn
from assurance.reasons import ReasonCode
from assurance.rtc import RtcPrefix
from kernel.core.jobs import JobResult
from skills.phases import TaskPhase
from skills.task_fsm import Requester


class LinkStatus(StrEnum):
    DOWN = "down"
    UP = "up"


class CameraStatus(StrEnum):
    """What the shell's camera watch saw of one camera (kernel/shell/cameras.py)."""

    LOST = "lost"
    """No frame, or none newer than the camera's ``max_frame_age_ms``."""
    FROZEN = "frozen"
    """The same picture ``freeze_frames`` times in a row: a sensor that stopped seeing."""
    BACK = "back"
    """Fresh, changing frames again."""


class ControllerStatus(StrEnum):
    OK = "ok"
    REJECT = "reject"
    """The device refused a command."""
    FAULT = "fault"
    PROTECTIVE_STOP = "protective_stop"
    ESTOP = "estop"


class RecorderFault(StrEnum):
    """Why the run's record (journal, decision log) can no longer be written."""

    NO_SPACE = "no_space"
    """The file system is full (ENOSPC), or the user's quota is (EDQUOT)."""
    READ_ONLY = "read_only"
    """The file system went read-only (EROFS), e.g. remounted after an error."""
    IO_ERROR = "io_error"
    """Any other write error (EIO, ...)."""


class OperatorAction(StrEnum):
    TAKEOVER = "takeover"
    RELEASE = "release"
    ACCEPT_RECOVERY = "accept_recovery"
    ESTOP = "estop"
    RESET = "reset"
    ABORT = "abort"


class StateEvent(msgspec.Struct, frozen=True, kw_only=True):
    t: int
    q: tuple[float, ...]
    qd: tuple[float, ...] | None = None
    force_residual: float | None = None


class FrameStamp(msgspec.Struct, frozen=True, kw_only=True):
    """One camera frame an observation carried, as the journal keeps it: not the pixels."""

    camera: str
    t_capture: int
    """The robot's clock when the frame was taken (ns)."""
    digest: str
    calibration_epoch: str


class ObservationEvent(msgspec.Struct, frozen=True, kw_only=True):
    t: int
    """When it was sent; its age counts from the oldest of its frames, if that is older."""
    observation_id: str
    rtc: RtcPrefix | None = None
    """The committed prefix the observation carried (real-time chunking), as it was sent."""
    frames: tuple[FrameStamp, ...] = ()
    """The camera frames it carried (protocol 3)."""


class CameraEvent(msgspec.Struct, frozen=True, kw_only=True):
    """A camera of the manifest was lost, froze, or came back (``detail``: what was seen)."""

    t: int
    camera: str
    status: CameraStatus
    detail: str = ""


class PhaseEvent(msgspec.Struct, frozen=True, kw_only=True):
    """A request to move the task to phase ``to``, by the task's own sequencing (``fsm``), the
    policy or an operator."""

    t: int
    to: TaskPhase
    evidence: dict[str, Any] = {}
    by: Requester = Requester.FSM


class ForceEvent(msgspec.Struct, frozen=True, kw_only=True):
    t: int
    residual: float


class OodEvent(msgspec.Struct, frozen=True, kw_only=True):
    t: int
    score: float


class LinkEvent(msgspec.Struct, frozen=True, kw_only=True):
    t: int
    status: LinkStatus


class HandshakeEvent(msgspec.Struct, frozen=True, kw_only=True):
    t: int
    offer: OfferIn


class OperatorEvent(msgspec.Struct, frozen=True, kw_only=True):
    """A human's command (``uid``: who gave it, read from the operator socket's peer)."""

    t: int
    action: OperatorAction
    uid: int | None = None


class ControllerEvent(msgspec.Struct, frozen=True, kw_only=True):
    """The controller's answer: ``ok``, a refused command (``reject``), a ``fault`` (with the
    driver's reason code, if it gave one), ``estop`` or ``protective_stop``."""

    t: int
    status: ControllerStatus
    reason: ReasonCode | None = None


class RecorderEvent(msgspec.Struct, frozen=True, kw_only=True):
    """The shell's recorder can no longer write the run's record: the core stops the arm
    (RECORDER_FAILED), and the run ends."""

    t: int
    fault: RecorderFault


class MoveEvent(msgspec.Struct, frozen=True, kw_only=True):
    """The task asks the planner for a classical rest-to-rest move to the joint ``target``
    (played while the planner owns the tick; ``move_id`` names it in the core's status)."""

    t: int
    move_id: int
    target: tuple[float, ...]


class GripperEvent(msgspec.Struct, frozen=True, kw_only=True):
    """The task sets the gripper's opening (metres); every later command carries it."""

    t: int
    opening: float


class InsertEvent(msgspec.Struct, frozen=True, kw_only=True):
    """The task starts the contact owner's guarded descent: along the vertical through ``xy``
    (metres, base frame) down to the TCP height ``z_end``, the tool held at ``rotation``
    (3×3, row-major)."""

    t: int
    xy: tuple[float, float]
    z_end: float
    rotation: tuple[float, ...]


class ComputedEvent(msgspec.Struct, frozen=True, kw_only=True):
    """A job the core asked for has finished (or failed): admission continues now."""

    t: int
    result: JobResult


class ClockSyncEvent(msgspec.Struct, frozen=True, kw_only=True):
    t: int
    domain: str
    offset: int
    round_trip: int


class TickEvent(msgspec.Struct, frozen=True, kw_only=True):
    """An explicit control tick (journals record them; scenario ticks are generated)."""

    t: int
    skipped: int = 0
    """Control periods that passed without a tick just before this one (a stall, as the
    loop's timer counted it). A record for the reader: the core decides from the gap
    between tick times."""


class ChunkEvent:
    """A chunk arrival at ``t`` (= client_receive). Not a Struct: it holds a numpy array.

    ``frame`` keeps the bytes exactly as they arrived when the chunk came off the wire, so a
    journal can replay the very same decode.
    """

    __slots__ = ("chunk", "frame", "t")

    def __init__(
        self, t: int, chunk: Chunk | MalformedChunk, frame: bytes | None = None
    ) -> None:
        self.t = t
        self.chunk = chunk
        self.frame = frame


Event = (
    StateEvent | ObservationEvent | PhaseEvent | ForceEvent | OodEvent | LinkEvent
    | HandshakeEvent | OperatorEvent | ControllerEvent | ClockSyncEvent | TickEvent | ChunkEvent
    | MoveEvent | GripperEvent | InsertEvent | ComputedEvent | RecorderEvent | CameraEvent
)

OPERATOR_ACTIONS = tuple(OperatorAction)
CONTROLLER_STATUSES = tuple(ControllerStatus)
LINK_STATUSES = tuple(LinkStatus)
CAMERA_STATUSES = tuple(CameraStatus)
RECORDER_FAULTS = tuple(RecorderFault)
REQUESTERS = tuple(Requester)
