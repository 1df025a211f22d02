"""What the core asks the shell to do: typed effects, returned with the decision-log lines.

Every command that reaches a driver is one of the motion effects below, decided by the core on
a control tick (exactly one per tick). The shell executes effects and decides nothing: it turns
a :class:`Setpoint` into the driver's position (or impedance) command, a :class:`Hold` into the
device's own hold, a :class:`Stop` into a stop; it answers :class:`RequestObservation` by
capturing and sending an observation, :class:`EndSession` by closing the policy session, and
:class:`Compute` by running the job off the control loop and feeding its result back as a
:class:`~kernel.core.events.ComputedEvent`.

Effects are frozen msgspec Structs with a tag, so the journal records a motion effect exactly
and a replay compares it bit for bit.
"""

from __future__ import annotations

import msgspec

from assurance.fallback import Owner
from assurance.handshake import HandshakeDecision
from assurance.reasons import ReasonCode
from kernel.core.jobs import Job
from kernel.core.lines import ADMITTED, Decision, Line

Vector = tuple[float, ...]


class Setpoint(msgspec.Struct, frozen=True, kw_only=True, tag_field="effect", tag="setpoint",
               omit_defaults=True):
    """A joint position setpoint for the next period; with stiffness and damping, a compliant
    (impedance) target for the contact owner."""

    q: Vector
    gripper: float | None
    owner: Owner
    chunk_id: str | None = None
    """The admitted chunk whose action this setpoint follows, if the policy owns the tick."""
    index: int | None = None
    stiffness: Vector = ()
    damping: Vector = ()


class Retreat(msgspec.Struct, frozen=True, kw_only=True, tag_field="effect", tag="retreat",
              omit_defaults=True):
    """A setpoint of a retreat: the planner's retreat trajectory or the contact owner's
    force-aware lift (then compliant, with stiffness and damping)."""

    q: Vector
    gripper: float | None
    owner: Owner
    stiffness: Vector = ()
    damping: Vector = ()


class Hold(msgspec.Struct, frozen=True, kw_only=True, tag_field="effect", tag="hold",
           omit_defaults=True):
    """The device holds where it is with its own position loop (a human has the arm)."""

    gripper: float | None
    owner: Owner
    reason: ReasonCode | None = None


class Stop(msgspec.Struct, frozen=True, kw_only=True, tag_field="effect", tag="stop",
           omit_defaults=True):
    """The device decelerates to standstill and stops streaming."""

    gripper: float | None
    owner: Owner
    reason: ReasonCode | None = None


Motion = Setpoint | Retreat | Hold | Stop
MOTION_TYPES = (Setpoint, Retreat, Hold, Stop)


class RequestObservation(msgspec.Struct, frozen=True, kw_only=True, tag_field="effect",
                         tag="request_observation"):
    """The queue is below its low watermark: capture an observation and send it for inference."""

    queue_depth: int


class EndSession(msgspec.Struct, frozen=True, kw_only=True, tag_field="effect",
                 tag="end_session"):
    """The core ended the policy session (DEGRADED): close it; only a new handshake reopens."""

    reason: ReasonCode


class Compute(msgspec.Struct, frozen=True, kw_only=True, tag_field="effect", tag="compute"):
    """Run ``job`` where it cannot delay a control tick; feed its result back as an event."""

    job: Job


Effect = Setpoint | Retreat | Hold | Stop | RequestObservation | EndSession | Compute


class ChunkDecision(msgspec.Struct, frozen=True, kw_only=True):
    """What admission decided on one chunk, for the shell (the policy link's counters and its
    backoff): produced with the chunk's decision-log line, whichever event decided it (the
    chunk's own, or the ``computed`` event of its job)."""

    chunk_id: str | None
    decision: Decision
    reasons: tuple[ReasonCode, ...] = ()

    @property
    def admitted(self) -> bool:
        return self.decision in ADMITTED


DecisionRecord = ChunkDecision | HandshakeDecision
"""A decision the core reports to the shell as a typed record (never read off a log line)."""


class Step(msgspec.Struct, frozen=True, eq=False):
    """What one event produced: decision-log lines, effects, and the decisions the shell acts
    on (chunks admitted or refused, handshakes), each in the order they arose."""

    lines: tuple[Line, ...]
    effects: tuple[Effect, ...]
    decisions: tuple[DecisionRecord, ...] = ()

    @property
    def motion(self) -> Motion | None:
        """The motion effect of a control tick (None for any other event)."""
        for effect in self.effects:
            if isinstance(effect, MOTION_TYPES):
                return effect
        return None


motion_decoder = msgspec.json.Decoder(Motion)
motion_encoder = msgspec.json.Encoder()
