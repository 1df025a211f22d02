"""The reference policy server: warden's policy-link peer, with fault injection.

It speaks ``docs/protocol.md`` through its own codec (``protocol.py``, ``handshake.py``,
``envelope.py``), never warden's, so a mistake in one side's codec is not copied into the
other. It speaks it honestly (clock pings answered from its own, deliberately offset clock; a
handshake offer; chunks only after the client's ``ACCEPT``; heartbeats both ways) and fills
every envelope field, so the robot side is exercised the way a real policy server would
exercise it. ``faults.py`` makes it misbehave on purpose.
"""

from __future__ import annotations

import asyncio
import itertools
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed

from peer.envelope import (
    ChunkEnvelope,
    Proposal,
    chunk_body_frame,
    chunk_envelope,
    encode_chunk_frame,
)
from peer.frames import ImageProblem, check_images
from peer.handshake import HandshakeOffer, HandshakeVerdict, fingerprint
from peer.listener import Listener
from peer.protocol import (
    Bye,
    ByeReason,
    ClockPing,
    ClockPong,
    ClockReport,
    Decision,
    Heartbeat,
    Hello,
    Message,
    MessageType,
    Observation,
    Offer,
    ProtocolViolation,
    array_payload,
    decode_body,
    decode_frame,
    encode,
    message_type,
    payload_vector,
)
from stubs.policy_server.cartesian import output_for
from stubs.policy_server.config import ServerConfig
from stubs.policy_server.faults import (
    ChunkFaults,
    FaultPlan,
    flood_chunks,
    flood_junk,
    garbage_chunk_body,
    garbage_frame,
    oversized_frame,
    unknown_type_frame,
)
from stubs.policy_server.images import decode_jpeg
from stubs.policy_server.rtc import ServerPrefix, conditioned_actions, read_prefix


@dataclass(slots=True)
class ServerStats:
    connections: int = 0
    hellos: list[Hello] = field(default_factory=list)
    decisions: list[Decision] = field(default_factory=list)
    fingerprints: list[str] = field(default_factory=list)
    """The server's own fingerprint for every ACCEPT it was sent."""
    observations: int = 0
    chunks_produced: int = 0
    chunks_sent: int = 0
    chunks_dropped: int = 0
    chunks_resent: int = 0
    violations: int = 0
    frames_seen: int = 0
    """Camera frames received and checked (protocol 3)."""
    frame_digests: list[str] = field(default_factory=list)
    """The last observation's frames' digests, in the order of the server's cameras."""
    byes_received: list[str] = field(default_factory=list)
    byes_sent: list[str] = field(default_factory=list)


class _Closed(Exception):
    def __init__(self, bye: ByeReason | None, detail: str = "") -> None:
        super().__init__(detail)
        self.bye = bye
        self.detail = detail


class PolicyServer:
    """``async with PolicyServer(config) as server:`` listens on ``server.port``."""

    def __init__(self, config: ServerConfig) -> None:
        self.config = config
        self.stats = ServerStats()
        self.policy = config.policy()
        self.output = output_for(config.action_frame, config.action_units)
        self.faults = FaultPlan(config.faults)
        self.source = config.chunk_source()
        self.rng = np.random.default_rng(config.seed)
        self.history: deque[tuple[int, bytes]] = deque(maxlen=64)
        """(epoch, frame) of every chunk produced, sent or not: what a resend can replay."""
        self._sequences: dict[int, itertools.count[int]] = {}
        self._listener = Listener()

    def now_ns(self) -> int:
        return time.monotonic_ns() + self.config.clock_offset_ns

    def next_sequence(self, epoch: int) -> int:
        return next(self._sequences.setdefault(epoch, itertools.count(1)))

    @property
    def port(self) -> int:
        return self._listener.port

    async def __aenter__(self) -> PolicyServer:
        config = self.config
        await self._listener.open(self._handle, config.host, config.port,
                                  config.max_frame_bytes, config.access)
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self._listener.close()

    async def serve_forever(self) -> None:
        await self._listener.serve_forever()

    async def _handle(self, ws: ServerConnection) -> None:
        index = self.stats.connections
        self.stats.connections += 1
        await _Connection(self, ws, index).run()


async def serve(config: ServerConfig, ready: Callable[[int], None] | None = None) -> None:
    """Run a server until cancelled; ``ready(port)`` is called once it listens."""
    async with PolicyServer(config) as server:
        if ready is not None:
            ready(server.port)
        await server.serve_forever()


class _Connection:
    def __init__(self, server: PolicyServer, ws: ServerConnection, index: int) -> None:
        self.server, self.ws, self.config = server, ws, server.config
        self.stats = server.stats
        self.faulty = index < self.config.faults.affect_connections
        self.hello: Hello | None = None
        self.offer: HandshakeOffer | None = None
        self.decided = self.accepted = self.stalled = False
        self.client_offset: int | None = None
        self.version: int | None = None
        self.held: bytes | None = None
        self.last_chunk: ChunkEnvelope | None = None
        """The last answer sent: what a chunk flood repeats under new ids."""
        self.delivered = 0
        self.last_rx = time.monotonic()
        self.tasks: asyncio.TaskGroup | None = None

    async def run(self) -> None:
        try:
            async with asyncio.TaskGroup() as tasks:
                self.tasks = tasks
                tasks.create_task(self._read())
                tasks.create_task(self._heartbeat())
        except* _Closed as group:
            await self._finish(group.exceptions[0])  # type: ignore[arg-type]

    async def _finish(self, closed: _Closed) -> None:
        if closed.bye is not None:
            try:
                await self.ws.send(encode(Bye(reason=closed.bye, detail=closed.detail)))
                self.stats.byes_sent.append(closed.bye)
            except ConnectionClosed:
                pass  # the client is gone already: nothing left to tell it
        await self.ws.close()

    async def _read(self) -> None:
        try:
            async for data in self.ws:
                self.last_rx = time.monotonic()
                await self._on_frame(data, self.server.now_ns())
        except ConnectionClosed as error:
            raise _Closed(None) from error
        except ProtocolViolation as error:
            self.stats.violations += 1
            raise _Closed(error.reason, error.detail) from error
        raise _Closed(None)

    async def _heartbeat(self) -> None:
        for seq in itertools.count(1):
            await asyncio.sleep(self.config.heartbeat_interval_s)
            if time.monotonic() - self.last_rx > self.config.heartbeat_timeout_s:
                raise _Closed(ByeReason.HEARTBEAT_TIMEOUT, "client silent")
            if not self.stalled:
                await self._send(Heartbeat(seq=seq, t_send=self.server.now_ns()))

    # -- messages --------------------------------------------------------------------------

    async def _on_frame(self, data: bytes | str, t: int) -> None:
        if self.stalled:
            return  # a stalled server answers nothing, heartbeats and pings included
        frame = decode_frame(data)
        kind = message_type(frame, self.version)
        if kind in (MessageType.CHUNK, MessageType.OFFER, MessageType.CLOCK_PONG):
            raise ProtocolViolation(f"a client does not send {kind}")
        message = decode_body(frame, kind)
        if isinstance(message, ClockPing):
            hostile = self.config.faults.clock_t_server if self.faulty else None
            await self._send(ClockPong(seq=message.seq, t0=message.t0,
                                       t_server=t if hostile is None else hostile))
        elif isinstance(message, Hello):
            await self._on_hello(message)
        elif isinstance(message, Decision):
            await self._on_decision(message)
        elif isinstance(message, ClockReport):
            self.client_offset = message.offset
        elif isinstance(message, Observation):
            self._on_observation(message, t)
        elif isinstance(message, Bye):
            self.stats.byes_received.append(message.reason)
            raise _Closed(None)

    async def _on_hello(self, hello: Hello) -> None:
        if self.hello is not None:
            raise ProtocolViolation("a second hello on one connection")
        wire = self.config.wire_protocol
        if max(hello.protocol[0], wire[0]) > min(hello.protocol[1], wire[1]):
            raise _Closed(ByeReason.UNSUPPORTED_VERSION, f"client speaks {hello.protocol}")
        self.hello = hello
        self.stats.hellos.append(hello)
        self.offer = self.config.offer(hello.hello.queue_epoch)
        if self.faulty and self.config.faults.chunk_before_offer:
            await self._send_chunk(self._unsolicited_chunk())
        await self._send(Offer(server_id=self.config.server_id, offer=self.offer))

    async def _on_decision(self, message: Decision) -> None:
        if self.hello is None or self.offer is None or self.decided:
            raise ProtocolViolation("a decision without an offer, or a second one")
        self.decided = True
        self.stats.decisions.append(message)
        decision = message.decision
        if decision.decision is not HandshakeVerdict.ACCEPT:
            return  # the client closes; nothing may be sent for a rejected session
        if decision.protocol is None:
            raise ProtocolViolation("an ACCEPT without a protocol version")
        own = fingerprint(self.hello.hello, self.offer, decision.protocol)
        self.stats.fingerprints.append(own)
        if own != decision.fingerprint:
            raise _Closed(ByeReason.FINGERPRINT_MISMATCH, f"server computed {own}")
        self.accepted, self.version = True, decision.protocol
        await self._resend(message.queue_epoch)
        self._start_floods()

    async def _resend(self, epoch: int) -> None:
        """Fault: replay chunks produced for earlier epochs, as a confused server would."""
        count = self.config.faults.resend_on_reconnect
        old = [frame for chunk_epoch, frame in self.server.history if chunk_epoch != epoch]
        for frame in old[-count:] if count else []:
            self.stats.chunks_resent += 1
            await self._send_chunk(frame)

    def _start_floods(self) -> None:
        faults = self.config.faults
        if not self.faulty or self.tasks is None:
            return
        if faults.flood_chunks_per_s > 0:
            unsolicited = self._unsolicited_envelope()  # until there is a last answer
            self.tasks.create_task(flood_chunks(
                faults.flood_chunks_per_s, lambda: self.last_chunk or unsolicited,
                self.server.next_sequence, self._send_chunk))
        if faults.junk_frame_bytes > 0:
            self.tasks.create_task(flood_junk(faults.junk_frame_bytes, faults.junk_frames_per_s,
                                              self._send_raw))

    def _on_observation(self, observation: Observation, t: int) -> None:
        if not self.accepted or self.tasks is None:
            raise ProtocolViolation("an observation before an accepted handshake")
        q = payload_vector(observation.q, len(self.config.goal))
        try:
            pixels = check_images(observation, self.config.cameras, self.version or 1,
                                  decode_jpeg)
        except ImageProblem as problem:
            raise ProtocolViolation(str(problem)) from None
        self.stats.frames_seen += len(pixels)
        self.stats.frame_digests = [image.digest for image in observation.images]
        # Real-time chunking: joint actions only (a Cartesian session's are not the rows).
        prefix = None if self.server.output is not None else read_prefix(
            self.config, observation.rtc, self.client_offset)
        self.stats.observations += 1
        self.tasks.create_task(self._infer(observation, q, t, prefix))

    # -- inference and delivery ------------------------------------------------------------

    async def _infer(self, observation: Observation, q: np.ndarray, t_arrival: int,
                     prefix: ServerPrefix | None) -> None:
        plan = self.server.faults.next_chunk()
        latency = self.config.latency.sample_s(self.server.rng) + plan.spike_s
        t_start = self.server.now_ns()
        if latency > 0:  # zero: answer in the same loop iteration, as a benchmark wants
            await asyncio.sleep(latency)
        await self._deliver(self._chunk(observation, q, t_arrival, t_start, plan, prefix), plan)

    def _chunk(self, observation: Observation, q: np.ndarray, t_arrival: int, t_start: int,
               plan: ChunkFaults, prefix: ServerPrefix | None = None) -> ChunkEnvelope:
        cfg = self.config
        # Observation time in this server's clock: the client's measured offset (protocol 2)
        # translates it; without one, the arrival time is the best this side knows.
        t_obs = t_arrival if self.client_offset is None else (
            observation.t_event - self.client_offset)
        # The joints were read after the frames were taken: the plan starts from then.
        t_state = t_obs if observation.t_state is None or self.client_offset is None else (
            observation.t_state - self.client_offset)
        qd = payload_vector(observation.qd, len(cfg.goal)) if observation.qd else None
        conditioned = None if prefix is None else conditioned_actions(
            cfg, self.server.policy, self.server.rng, prefix, qd)
        if conditioned is None:
            actions = self.server.policy.actions(q, cfg.lead_ns / 1e9, self.server.rng, qd)
            first, delay = t_state + cfg.lead_ns, None
        else:
            actions, delay, first = conditioned
        if self.server.output is not None:
            actions = self.server.output(q, actions)
        if plan.nonfinite:
            actions[len(actions) // 2, 0] = np.nan
        if plan.wrong_dim:
            actions = np.hstack([actions, np.zeros((len(actions), 1))])
        if self.faulty and cfg.faults.big_chunk_rows > 0:
            actions = np.resize(actions, (cfg.faults.big_chunk_rows, actions.shape[1]))
        epoch = observation.queue_epoch
        sequence = self.server.next_sequence(epoch)
        now = self.server.now_ns()
        return chunk_envelope(self.server.source, Proposal(
            chunk_id=f"{cfg.server_id}-e{epoch}-s{sequence}", sequence=sequence,
            queue_epoch=epoch, task_phase=observation.task_phase,
            observation_id=observation.observation_id, observed_q=q, actions=actions,
            first_action_time=first, observation_event_time=t_obs,
            observation_arrival_time=t_arrival, inference_start=t_start, inference_end=now,
            server_send=now, rtc_delay=delay,
        ))

    async def _deliver(self, chunk: ChunkEnvelope, plan: ChunkFaults) -> None:
        frame = (chunk_body_frame(garbage_chunk_body(chunk)) if plan.garbage
                 else encode_chunk_frame(chunk))
        self.server.history.append((chunk.queue_epoch, frame))
        self.last_chunk = chunk
        self.stats.chunks_produced += 1
        if self.stalled or plan.drop:
            self.stats.chunks_dropped += 1
            return
        if plan.reorder and self.held is None:
            self.held = frame  # sent after the next chunk
            return
        await self._send_chunk(frame)
        if plan.duplicate:
            await self._send_chunk(frame)
        if self.held is not None:
            held, self.held = self.held, None
            await self._send_chunk(held)
        self.delivered += 1
        if self.faulty:
            await self._connection_faults(self.delivered)

    async def _connection_faults(self, delivered: int) -> None:
        faults = self.config.faults
        extra = {faults.garbage_frame_after: garbage_frame,
                 faults.oversized_after: oversized_frame,
                 faults.unknown_type_after: unknown_type_frame}
        for after, make in extra.items():
            if after == delivered:
                await self._send_raw(make())
        if faults.stall_after == delivered:
            self.stalled = True
        if faults.close_after == delivered:
            raise _Closed(ByeReason.FAULT_INJECTED, f"closing after {delivered} chunks")

    def _unsolicited_chunk(self) -> bytes:
        return encode_chunk_frame(self._unsolicited_envelope())

    def _unsolicited_envelope(self) -> ChunkEnvelope:
        """A chunk answering no observation the client sent."""
        epoch = self.hello.hello.queue_epoch if self.hello else 0
        q = np.asarray(self.config.goal, dtype=float)
        observation = Observation(
            observation_id="unsolicited", t_event=0, queue_epoch=epoch, task_phase="FREE_SPACE",
            q=array_payload(q))
        now = self.server.now_ns()
        return self._chunk(observation, q, now, now, ChunkFaults())

    # -- sending ---------------------------------------------------------------------------

    async def _send(self, message: Message) -> None:
        await self._send_raw(encode(message))

    async def _send_chunk(self, frame: bytes) -> None:
        await self._send_raw(frame)
        self.stats.chunks_sent += 1

    async def _send_raw(self, data: bytes) -> None:
        try:
            await self.ws.send(data)
        except ConnectionClosed as error:
            raise _Closed(None) from error

