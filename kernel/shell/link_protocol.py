"""The policy link's session logic without I/O (h11's pattern): frames and times in; frames to
send, events for the core and the connection's end out.

A :class:`LinkProtocol` owns no socket, task or clock. The shell hands it each frame it read with
the instant it read it (:meth:`~LinkProtocol.receive_frame`), wakes it at the instant it asked
for (:meth:`~LinkProtocol.next_deadline`, :meth:`~LinkProtocol.timeout`), hands it each decision
the core made (typed, from ``Core.step``) and each admission slot, and carries out what it
returns: :class:`Send` a frame, :class:`Feed` an event to the core, :class:`HelloDue` (give the
robot's side of the handshake now), :class:`OfferArrived` (have the core decide it),
:class:`ChunksWaiting` (call :meth:`~LinkProtocol.next_chunk` at the next admission slot),
:class:`ObservationDue` (capture the robot, call :meth:`~LinkProtocol.observe`), :class:`Ended`.
Every timing decision of the link is made here, on the times passed in: heartbeats, the peer's
silence, the handshake's and the clock pings' timeouts, the clock exchange and its refresh
(:mod:`kernel.shell.link_protocol_timers`), the frame and chunk rates, the window of requests
in flight and the chunk queue (:mod:`kernel.shell.link_protocol_budget`). The asyncio client
(:mod:`kernel.shell.client`) moves bytes through it over a websocket and sleeps until its next
deadline; a lockstep run drives the same object over an in-memory pipe on the virtual clock
(``stubs/cell/local_policy.py``).

:class:`WardenProtocol` is warden's own wire protocol (docs/protocol.md); another policy
protocol is another class with the same methods (docs/architecture.md, "A chunk's path through
the link").
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass
from typing import Protocol

from assurance.envelope import Chunk, MalformedChunk, decode_wire_chunk
from assurance.handshake import ClientHello, HandshakeDecision, HandshakeOffer, HandshakeVerdict
from kernel import wire
from kernel.core import events as ev
from kernel.core.effects import ChunkDecision, DecisionRecord
from kernel.shell.link_protocol_budget import ChunkQueue, RequestWindow, TokenBucket
from kernel.shell.link_protocol_timers import ClockExchange, Liveness
from kernel.shell.link_rtc import PrefixPlanner
from kernel.shell.link_types import LinkCounters, LinkTiming, RobotSample
from kernel.wire import ByeReason, ClockSample, MessageType, ProtocolViolation


@dataclass(frozen=True, slots=True)
class Send:
    """A frame to send to the peer."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Feed:
    """An event for the core."""

    event: ev.Event


@dataclass(frozen=True, slots=True)
class HelloDue:
    """The protocol's own opening (the clock exchange) is done: call
    :meth:`LinkProtocol.hello` with the robot's side of the handshake as of now."""


@dataclass(frozen=True, slots=True)
class OfferArrived:
    """The peer's handshake offer (after the robot's hello): have the core decide it
    (:meth:`LinkProtocol.handshake_event`) and hand its decision back."""

    offer: HandshakeOffer


@dataclass(frozen=True, slots=True)
class ChunksWaiting:
    """A chunk of the session waits for an admission slot (:meth:`LinkProtocol.next_chunk`)."""


@dataclass(frozen=True, slots=True)
class ObservationDue:
    """The core asked for an inference and the window of requests in flight has room:
    capture the robot now (with the committed actions on ``prefix_grid_ns``'s grid, when
    set: real-time chunking) and call :meth:`LinkProtocol.observe`."""

    prefix_grid_ns: int | None = None


@dataclass(frozen=True, slots=True)
class Ended:
    """This connection is over; ``bye`` is what to tell the peer (None: nothing to say)."""

    bye: ByeReason | None
    detail: str


Output = Send | Feed | HelloDue | OfferArrived | ChunksWaiting | ObservationDue | Ended


class LinkProtocol(Protocol):
    """What the shell needs of a policy wire protocol (warden's, or another policy server's).

    Every ``now_ns`` is the core's clock (the gateway's ``now_ns``) at the instant the shell
    acts; a connection emits :class:`Ended` at most once, and nothing after it.
    """

    counters: LinkCounters
    says_goodbye: bool
    """Whether the peer's protocol has a goodbye (warden's ``Bye``) the client sends at the end."""
    accepted: bool
    version: int | None
    """The negotiated protocol version of the session (None: none accepted)."""
    fingerprint: str | None

    def connect(self, now_ns: int) -> list[Output]:
        """A new connection, open at ``now_ns``: nothing of an earlier one carries over."""
        ...

    def close(self) -> None:
        """The shell ended the connection: nothing more is due, queued chunks are dropped."""
        ...

    def hello(self, side: ClientHello, now_ns: int) -> list[Output]: ...

    def receive_frame(self, data: bytes | str, now_ns: int) -> list[Output]:
        """One frame from the peer, read at ``now_ns`` (a protocol violation: :class:`Ended`)."""
        ...

    def next_deadline(self) -> int | None:
        """When :meth:`timeout` must next be called (None: nothing is timed)."""
        ...

    def timeout(self, now_ns: int) -> list[Output]:
        """What is due by ``now_ns``: heartbeats, pings, the end of a silent peer."""
        ...

    def handshake_event(self, offer: HandshakeOffer, now_ns: int) -> ev.HandshakeEvent: ...

    def on_decision(self, record: DecisionRecord, queue_epoch: int,
                    now_ns: int) -> list[Output]:
        """What the core decided (a handshake, a chunk): the frames and the end it implies."""
        ...

    def request(self, now_ns: int) -> list[Output]:
        """The core asked for an inference (requests coalesce until one goes out)."""
        ...

    def observe(self, sample: RobotSample, now_ns: int, queue_epoch: int) -> list[Output]:
        """The observation's event and its frame."""
        ...

    @property
    def chunks_waiting(self) -> int: ...

    def next_chunk(self, now_ns: int) -> list[Output]:
        """An admission slot: the next waiting chunk's event, decoded now."""
        ...


class WardenProtocol:
    """Warden's policy protocol (docs/protocol.md), one object for the client's lifetime."""

    says_goodbye = True

    def __init__(self, client_id: str, protocol: tuple[int, int], counters: LinkCounters,
                 timing: LinkTiming) -> None:
        self.client_id, self.protocol, self.counters = client_id, protocol, counters
        self.timing = timing
        self.accepted = False
        self.version: int | None = None
        self.fingerprint: str | None = None
        self._observation_ids = itertools.count(1)
        self._frames = TokenBucket(timing.max_frames_per_s)
        self._window = RequestWindow(timing.max_requests_in_flight, timing.request_timeout_ns)
        self._chunks = ChunkQueue(timing.max_chunks_per_s, self._window, counters)
        self._rtc = PrefixPlanner()
        self._clock = ClockExchange(timing.clock_burst, timing.clock_ping_timeout_ns,
                                    timing.clock_refresh_ns)
        self._liveness = Liveness(timing.heartbeat_interval_ns, timing.heartbeat_timeout_ns)
        self._open = False
        self._hello_sent = self._offered = False
        self._offer: HandshakeOffer | None = None
        self._handshake_by: int | None = None
        self._wanted = self._held = False

    @property
    def clock(self) -> ClockSample | None:
        """The clock sync in force (the last burst's best sample, kept across connections)."""
        return self._clock.sample

    # -- the connection --------------------------------------------------------------------

    def connect(self, now_ns: int) -> list[Output]:
        self.accepted, self.version, self._open = False, None, True
        self._hello_sent = self._offered = self._wanted = self._held = False
        self._offer = None
        self._window.clear()
        self._chunks.clear()
        self._rtc.begin(offered=False, chunk_horizon=0)
        self._clock.begin()
        self._liveness.begin(now_ns)
        self._handshake_by = now_ns + self.timing.handshake_timeout_ns
        if self._clock.burst == 0:
            return [HelloDue()]
        return [self._send(self._clock.start(now_ns))]

    def close(self) -> None:
        self._open = self._wanted = False
        self._handshake_by = None
        self._chunks.clear()

    def _end(self, bye: ByeReason | None, detail: str) -> list[Output]:
        self.close()
        return [Ended(bye, detail)]

    def hello(self, side: ClientHello, now_ns: int) -> list[Output]:
        if not self._open or self._hello_sent:
            return []
        self._hello_sent = True
        sent = self._send(wire.Hello(client_id=self.client_id, protocol=self.protocol,
                                     hello=side))
        return [sent, *self._offer_arrived()]

    # -- time ------------------------------------------------------------------------------

    def next_deadline(self) -> int | None:
        if not self._open:
            return None
        due = [self._liveness.deadline()]
        for deadline in (self._clock.deadline(), self._handshake_by,
                         self._window.deadline() if self._wanted else None):
            if deadline is not None:
                due.append(deadline)
        return min(due)

    def timeout(self, now_ns: int) -> list[Output]:
        if not self._open:
            return []
        silent = self._liveness.silent_for(now_ns)
        if silent is not None:
            self.counters.link_timeouts += 1
            return self._end(ByeReason.HEARTBEAT_TIMEOUT, f"peer silent for {silent / 1e9:.3f} s")
        if self._clock.ping_timed_out(now_ns):
            return self._end(ByeReason.CLOCK_TIMEOUT, "clock ping unanswered")
        if self._handshake_by is not None and now_ns >= self._handshake_by:
            return self._end(ByeReason.HANDSHAKE_TIMEOUT, "no offer in time")
        outputs: list[Output] = []
        for seq, late in self._liveness.due(now_ns):
            self.counters.heartbeat_misses += late  # the peer's heartbeat (or anything) is late
            outputs.append(self._send(wire.Heartbeat(seq=seq, t_send=now_ns)))
        if self._clock.refresh_due(now_ns):
            outputs.append(self._send(self._clock.start(now_ns)))
        return [*outputs, *self._observation_due(now_ns)]

    # -- frames in -------------------------------------------------------------------------

    def receive_frame(self, data: bytes | str, now_ns: int) -> list[Output]:
        if not self._open:
            return []
        self._liveness.heard(now_ns)  # any frame shows the peer alive, a dropped one too
        self.counters.frames_in += 1
        self.counters.bytes_in += len(data)
        if not self._frames.take(now_ns):
            self.counters.frames_dropped += 1  # over the frame rate: not even decoded
            return []
        try:
            return self._receive(data, now_ns)
        except ProtocolViolation as error:
            self.counters.protocol_violations += 1
            return self._end(error.reason, error.detail)

    def _receive(self, data: bytes | str, now_ns: int) -> list[Output]:
        frame = wire.decode_frame(data)
        kind = wire.message_type(frame, self.version)
        if kind is MessageType.CHUNK:
            if not self.accepted:  # never let a chunk reach the core outside a session
                raise ProtocolViolation("chunk before the session was accepted")
            return [ChunksWaiting()] if self._chunks.put(frame, now_ns) else []
        message = wire.decode_body(frame, kind)
        if isinstance(message, wire.ClockPong):
            return self._pong(message, now_ns)
        if isinstance(message, wire.Offer):
            if self._offered:
                return []  # only the first offer of a connection is decided
            self._offered, self._offer = True, message.offer
            self._rtc.begin(message.offer.rtc, message.offer.chunk_horizon)
            return self._offer_arrived()
        if isinstance(message, wire.Bye):
            self.counters.byes_received += 1
            return self._end(None, f"server said bye: {message.reason[:40]}")
        if isinstance(message, wire.Heartbeat):
            return []
        raise ProtocolViolation(f"unexpected {kind} from the server")

    def _offer_arrived(self) -> list[Output]:
        """The offer, once the robot's hello is out (a server answers a hello)."""
        if self._offer is None or not self._hello_sent:
            return []
        offer, self._offer, self._handshake_by = self._offer, None, None
        return [OfferArrived(offer)]

    def _pong(self, pong: wire.ClockPong, now_ns: int) -> list[Output]:
        answer = self._clock.pong(pong, now_ns)
        if answer is None:
            return []
        self.counters.clock_round_trips += 1
        if isinstance(answer, wire.ClockPing):
            return [self._send(answer)]
        self.counters.clock_syncs += 1
        synced = Feed(ev.ClockSyncEvent(t=now_ns, domain=wire.SERVER_CLOCK_DOMAIN,
                                        offset=answer.offset, round_trip=answer.round_trip))
        if not self.accepted:
            return [synced, HelloDue()]
        self._clock.schedule_refresh(now_ns)
        return [synced, *self._report()]

    def _report(self) -> list[Output]:
        """The sync in force, told to a protocol-2 server."""
        sample = self._clock.sample
        if self.version is None or self.version < 2 or sample is None:
            return []
        return [self._send(wire.ClockReport(offset=sample.offset, round_trip=sample.round_trip))]

    def handshake_event(self, offer: HandshakeOffer, now_ns: int) -> ev.HandshakeEvent:
        return ev.HandshakeEvent(t=now_ns, offer=offer)

    # -- the core's decisions --------------------------------------------------------------

    def on_decision(self, record: DecisionRecord, queue_epoch: int,
                    now_ns: int) -> list[Output]:
        if isinstance(record, ChunkDecision):
            self.counters.chunk_decided(record.admitted)
            return []
        return self._decided(record, queue_epoch, now_ns)

    def _decided(self, decision: HandshakeDecision, queue_epoch: int,
                 now_ns: int) -> list[Output]:
        sent = self._send(wire.Decision(decision=decision, queue_epoch=queue_epoch))
        if decision.decision != HandshakeVerdict.ACCEPT or decision.protocol is None:
            self.counters.handshakes_rejected += 1
            return [sent, *self._end(ByeReason.HANDSHAKE_REJECTED, ",".join(decision.reasons))]
        self.counters.handshakes_accepted += 1
        self.accepted, self.version = True, decision.protocol
        self.fingerprint = decision.fingerprint
        self._wanted = self._held = False  # requests before the handshake are not for it
        self._window.clear()
        if self._clock.burst:
            self._clock.schedule_refresh(now_ns)
        return [sent, *self._report()]

    # -- observations out, chunks in -------------------------------------------------------

    def request(self, now_ns: int) -> list[Output]:
        if not (self._open and self.accepted):
            return []
        self._wanted = True
        return self._observation_due(now_ns)

    def _observation_due(self, now_ns: int) -> list[Output]:
        """One observation for the requests made, once the window has room."""
        if not self._wanted:
            return []
        room = self._window.open(now_ns)
        self.counters.requests_expired = self._window.expired
        if room:
            self._wanted = self._held = False
            return [ObservationDue(self._rtc.grid_ns())]
        if not self._held:  # enough in flight: sent when one is answered or expires
            self._held = True
            self.counters.requests_waited += 1
        return []

    def observe(self, sample: RobotSample, now_ns: int, queue_epoch: int) -> list[Output]:
        """One observation of ``sample``, sent ``now_ns``; it is as old as its oldest frame
        (frames travel from protocol 3 on: the manifest allows no lower version with cameras)."""
        observation_id = f"{self.client_id}/{next(self._observation_ids)}"
        prefix = self._rtc.prefix(sample.committed, now_ns)
        if sample.images and (self.version or 0) < wire.IMAGE_PROTOCOL:
            sample = dataclasses.replace(sample, images=())
        images = sample.images
        frame = self._send(wire.Observation(
            observation_id=observation_id, t_event=sample.taken_at(now_ns), queue_epoch=queue_epoch,
            task_phase=str(sample.task_phase), q=wire.vector_payload(sample.q),
            qd=wire.optional_payload(sample.qd), wrench=wire.optional_payload(sample.wrench),
            gripper=sample.gripper, rtc=None if prefix is None else wire.prefix_payload(prefix),
            images=tuple(image.payload() for image in images),
            t_state=sample.measured_at(now_ns) if images else None))
        self._window.sent(observation_id, now_ns)
        self.counters.observations_sent += 1
        return [Feed(ev.ObservationEvent(t=now_ns, observation_id=observation_id, rtc=prefix,
                                         frames=tuple(image.stamp() for image in images))),
                frame]

    @property
    def chunks_waiting(self) -> int:
        return len(self._chunks) if self._open else 0

    @property
    def requests_in_flight(self) -> int:
        return len(self._window)

    def next_chunk(self, now_ns: int) -> list[Output]:
        frame = self._chunks.pop() if self._open else None
        if frame is None:
            return []
        event = self.chunk_event(frame, now_ns)
        chunk = event.chunk  # a fed chunk answers its request, whatever the core decides
        sent = self._window.answered(chunk.observation_id if isinstance(chunk, Chunk) else None)
        if sent is not None and isinstance(chunk, Chunk):
            self._rtc.answered(now_ns - sent, chunk.time("action_dt"))
        return [Feed(event), *self._observation_due(now_ns)]

    def chunk_event(self, frame: wire.Frame, now_ns: int) -> ev.ChunkEvent:
        """The chunk, decoded at the instant it is decided (the core's clock only moves
        forward); a body that does not decode is counted and fed as malformed."""
        chunk = decode_wire_chunk(frame.body, now_ns)
        if isinstance(chunk, MalformedChunk):
            self.counters.malformed += 1
        return ev.ChunkEvent(now_ns, chunk, bytes(frame.body))

    @staticmethod
    def _send(message: wire.Message) -> Send:
        return Send(wire.encode(message))
