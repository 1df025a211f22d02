"""The policy link's session logic without I/O (h11's pattern): frames and times in; frames to
send, events for the core and the connection's end out.

A :class:`LinkProtocol` owns no socket, task or clock: the shell hands it each frame it read
with the instant it read it, and each decision the core made (typed, from ``Core.step``), and
carries out what it returns: :class:`Send` a frame, :class:`Feed` an event to the core,
:class:`ChunkArrived` (a chunk frame for the bounded intake, decoded only when its admission
slot comes: :meth:`LinkProtocol.chunk_event`), :class:`OfferArrived`, :class:`PongArrived`,
:class:`Ended`. The asyncio client moves bytes through it over a websocket; a lockstep run
drives the same object over an in-memory pipe (``stubs/cell/local_policy.py``).

:class:`WardenProtocol` is warden's own wire protocol (docs/protocol.md); another policy
protocol is another class with the same methods.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Protocol

from assurance.envelope import MalformedChunk, decode_wire_chunk
from assurance.handshake import ClientHello, HandshakeDecision, HandshakeOffer, HandshakeVerdict
from kernel import wire
from kernel.core import events as ev
from kernel.core.effects import ChunkDecision, DecisionRecord
from kernel.shell.link_types import LinkCounters, RobotSample
from kernel.wire import ByeReason, MessageType, ProtocolViolation


@dataclass(frozen=True, slots=True)
class Send:
    """A frame to send to the peer."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Feed:
    """An event for the core."""

    event: ev.Event


@dataclass(frozen=True, slots=True)
class OfferArrived:
    """The peer's handshake offer: the shell feeds :meth:`LinkProtocol.handshake_event` once
    its own side of the handshake (clock sync, hello) is done."""

    offer: HandshakeOffer


@dataclass(frozen=True, slots=True)
class ChunkArrived:
    """A chunk frame of the accepted session, for the intake's bounded queue."""

    frame: wire.Frame


@dataclass(frozen=True, slots=True)
class PongArrived:
    pong: wire.ClockPong
    t_receive: int


@dataclass(frozen=True, slots=True)
class Ended:
    """This connection is over; ``bye`` is what to tell the peer (None: nothing to say)."""

    bye: ByeReason | None
    detail: str


Output = Send | Feed | OfferArrived | ChunkArrived | PongArrived | Ended


class LinkProtocol(Protocol):
    """What the shell needs of a policy wire protocol (warden's, or another policy server's)."""

    counters: LinkCounters

    def begin(self) -> None:
        """A new connection: nothing of an earlier one carries over."""
        ...

    def hello(self, side: ClientHello) -> list[Output]:
        """The robot's side of the handshake (``side``: with the core's queue epoch now)."""
        ...

    def receive_frame(self, data: bytes | str, now_ns: int) -> list[Output]:
        """One frame from the peer, read at ``now_ns``.

        Raises:
            ProtocolViolation: the peer broke the protocol (the end of the connection).
        """
        ...

    def handshake_event(self, offer: HandshakeOffer, now_ns: int) -> ev.HandshakeEvent: ...

    def chunk_event(self, frame: wire.Frame, now_ns: int) -> ev.ChunkEvent: ...

    def on_decision(self, record: DecisionRecord, queue_epoch: int) -> list[Output]:
        """What the core decided (a handshake, a chunk): the frames and the end it implies."""
        ...

    def observe(self, sample: RobotSample, now_ns: int, queue_epoch: int) -> list[Output]:
        """The core asked for an inference: the observation's event and its frame."""
        ...


class WardenProtocol:
    """Warden's policy protocol (docs/protocol.md), one object for the client's lifetime."""

    def __init__(self, client_id: str, protocol: tuple[int, int],
                 counters: LinkCounters) -> None:
        self.client_id = client_id
        self.protocol = protocol
        self.counters = counters
        self._observation_ids = itertools.count(1)
        self.accepted = False
        self.version: int | None = None
        self.fingerprint: str | None = None
        self._offered = False

    def begin(self) -> None:
        self.accepted, self.version, self._offered = False, None, False

    def hello(self, side: ClientHello) -> list[Output]:
        return [self._send(wire.Hello(client_id=self.client_id, protocol=self.protocol,
                                      hello=side))]

    # -- frames in -------------------------------------------------------------------------

    def receive_frame(self, data: bytes | str, now_ns: int) -> list[Output]:
        frame = wire.decode_frame(data)
        kind = wire.message_type(frame, self.version)
        if kind is MessageType.CHUNK:
            if not self.accepted:  # never let a chunk reach the core outside a session
                raise ProtocolViolation("chunk before the session was accepted")
            return [ChunkArrived(frame)]
        message = wire.decode_body(frame, kind)
        if isinstance(message, wire.ClockPong):
            return [PongArrived(message, now_ns)]
        if isinstance(message, wire.Offer):
            if self._offered:
                return []  # only the first offer of a connection is decided
            self._offered = True
            return [OfferArrived(message.offer)]
        if isinstance(message, wire.Bye):
            self.counters.byes_received += 1
            return [Ended(None, f"server said bye: {message.reason[:40]}")]
        if isinstance(message, wire.Heartbeat):
            return []
        raise ProtocolViolation(f"unexpected {kind} from the server")

    def handshake_event(self, offer: HandshakeOffer, now_ns: int) -> ev.HandshakeEvent:
        return ev.HandshakeEvent(t=now_ns, offer=offer)

    def chunk_event(self, frame: wire.Frame, now_ns: int) -> ev.ChunkEvent:
        """The chunk, decoded at the instant it is decided (the core's clock only moves
        forward); a body that does not decode is counted and fed as malformed."""
        chunk = decode_wire_chunk(frame.body, now_ns)
        if isinstance(chunk, MalformedChunk):
            self.counters.malformed += 1
        return ev.ChunkEvent(now_ns, chunk, bytes(frame.body))

    # -- the core's decisions --------------------------------------------------------------

    def on_decision(self, record: DecisionRecord, queue_epoch: int) -> list[Output]:
        if isinstance(record, ChunkDecision):
            self.counters.chunks_admitted += record.admitted
            self.counters.chunks_refused += not record.admitted
            return []
        return self._decided(record, queue_epoch)

    def _decided(self, decision: HandshakeDecision, queue_epoch: int) -> list[Output]:
        sent = self._send(wire.Decision(decision=decision, queue_epoch=queue_epoch))
        if decision.decision != HandshakeVerdict.ACCEPT or decision.protocol is None:
            self.counters.handshakes_rejected += 1
            return [sent, Ended(ByeReason.HANDSHAKE_REJECTED, ",".join(decision.reasons))]
        self.counters.handshakes_accepted += 1
        self.accepted, self.version = True, decision.protocol
        self.fingerprint = decision.fingerprint
        return [sent]

    # -- observations out ------------------------------------------------------------------

    def observe(self, sample: RobotSample, now_ns: int, queue_epoch: int) -> list[Output]:
        observation_id = f"{self.client_id}/{next(self._observation_ids)}"
        frame = self._send(wire.Observation(
            observation_id=observation_id, t_event=now_ns, queue_epoch=queue_epoch,
            task_phase=str(sample.task_phase), q=wire.vector_payload(sample.q),
            qd=wire.optional_payload(sample.qd), wrench=wire.optional_payload(sample.wrench),
            gripper=sample.gripper))
        return [Feed(ev.ObservationEvent(t=now_ns, observation_id=observation_id)), frame]

    @staticmethod
    def _send(message: wire.Message) -> Send:
        return Send(wire.encode(message))
