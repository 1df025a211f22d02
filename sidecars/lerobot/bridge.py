"""The sidecar's warden side: a policy server of warden's own protocol whose policy is a
LeRobot PolicyServer reached over gRPC.

One robot at a time (LeRobot's ``Ready`` resets its server for whoever calls it, so a second
robot would take the first one's policy away): a second connection is closed at once with code
1013, "try again later". Per robot session:

- the handshake offers what the configuration declares (``config.py``); after ``ACCEPT`` the
  sidecar calls ``Ready`` and ``SendPolicyInstructions`` (the server loads the policy);
- each observation is checked (its joints, every configured camera's raw frame, exactly), turned
  into LeRobot's raw observation and kept as the one pending; a newer one replaces it, as
  LeRobot's own queue of one does;
- one inference at a time: the pending observation goes out with ``must_go`` set (every warden
  observation asks for a chunk; LeRobot's similarity filter would otherwise drop most of them),
  and the reply is read by ``replies.py`` and checked by ``mapping.py`` before it becomes a
  chunk. A refused reply is logged and counted, and no chunk is sent: warden's own timeouts
  decide what the arm does without one;
- a failed gRPC call ends the session with ``bye`` (``session_ended``, the call and its status),
  so warden sees its policy gone and reconnects, which prepares the server again.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import time
from collections import deque
from dataclasses import dataclass, field
from typing import cast

import numpy as np
from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed

from peer.envelope import ChunkSource, Proposal, chunk_frame
from peer.frames import CameraShape, ImageProblem, check_images
from peer.handshake import HandshakeOffer, HandshakeVerdict, fingerprint
from peer.listener import Listener
from peer.protocol import (
    MAX_FRAME_BYTES,
    PROTOCOL_RANGE,
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
    decode_body,
    decode_frame,
    encode,
    message_type,
    payload_vector,
)
from sidecars.lerobot import pickles
from sidecars.lerobot.config import SidecarConfig
from sidecars.lerobot.grpc_link import LeRobotLink, LinkLost
from sidecars.lerobot.mapping import (
    ReplyMismatch,
    Sent,
    first_time,
    lerobot_observation,
    reply_actions,
)
from sidecars.lerobot.replies import ReplyRefused, read_reply

log = logging.getLogger("sidecars.lerobot")

HEARTBEAT_INTERVAL_S = 0.1
HEARTBEAT_TIMEOUT_S = 1.0
RECENT = 1000
BUSY_CLOSE_CODE = 1013
"""Websocket "try again later": the sidecar serves another robot."""


@dataclass(slots=True)
class SidecarStats:
    sessions: int = 0
    refused_busy: int = 0
    observations: int = 0
    superseded: int = 0
    """Observations replaced by a newer one before they went to LeRobot."""
    inferences: int = 0
    chunks_sent: int = 0
    replies_refused: int = 0
    last_refusal: str = ""
    empty_replies: int = 0
    prepare_s: deque[float] = field(default_factory=lambda: deque(maxlen=RECENT))
    inference_s: deque[float] = field(default_factory=lambda: deque(maxlen=RECENT))
    """The latest round trips to LeRobot (a sidecar runs for days: only the recent ones)."""


class Sidecar:
    """``async with Sidecar(config) as sidecar:`` listens on ``sidecar.port``."""

    def __init__(self, config: SidecarConfig) -> None:
        self.config = config
        self.setup = config.policy_setup()
        self.stats = SidecarStats()
        self.busy = False
        self._listener = Listener()

    @property
    def port(self) -> int:
        return self._listener.port

    def offer(self, queue_epoch: int) -> HandshakeOffer:
        return self.config.offer_for(self.setup, queue_epoch)

    async def __aenter__(self) -> Sidecar:
        listen = self.config.listen
        frames = sum(camera.width * camera.height * 3 for camera in self.config.cameras)
        await self._listener.open(self._handle, listen.host, listen.port,
                                  max(MAX_FRAME_BYTES, frames + (64 << 10)), listen.access())
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self._listener.close()

    async def serve_forever(self) -> None:
        await self._listener.serve_forever()

    async def _handle(self, ws: ServerConnection) -> None:
        if self.busy:
            self.stats.refused_busy += 1
            await ws.close(BUSY_CLOSE_CODE, "the sidecar serves another robot")
            return
        self.busy = True
        self.stats.sessions += 1
        try:
            await _Session(self, ws).run()
        finally:
            self.busy = False


class _Ended(Exception):
    def __init__(self, bye: ByeReason | None, detail: str = "") -> None:
        super().__init__(detail)
        self.bye, self.detail = bye, detail


class _Session:
    def __init__(self, sidecar: Sidecar, ws: ServerConnection) -> None:
        self.sidecar, self.ws, self.config = sidecar, ws, sidecar.config
        self.stats = sidecar.stats
        self.cameras = tuple(CameraShape(c.warden, c.width, c.height)
                             for c in self.config.cameras)
        self.hello: Hello | None = None
        self.offer: HandshakeOffer | None = None
        self.version: int | None = None
        self.client_offset: int | None = None
        """``t_client = t_sidecar + offset`` once warden reported it (protocol 2)."""
        self.accepted = asyncio.Event()
        self.pending: tuple[Sent, bytes] | None = None
        self.wake = asyncio.Event()
        self.timesteps = itertools.count()
        self.sequences: dict[int, itertools.count[int]] = {}
        self.last_rx = time.monotonic()

    async def run(self) -> None:
        try:
            async with asyncio.TaskGroup() as tasks:
                tasks.create_task(self._read())
                tasks.create_task(self._heartbeat())
                tasks.create_task(self._serve_policy())
        except* _Ended as group:
            await self._finish(cast(_Ended, group.exceptions[0]))

    async def _finish(self, ended: _Ended) -> None:
        if ended.detail:
            log.warning("session ended: %s", ended.detail)
        if ended.bye is not None:
            with contextlib.suppress(ConnectionClosed):  # warden may be gone already
                await self.ws.send(encode(Bye(reason=ended.bye, detail=ended.detail[:200])))
        await self.ws.close()

    # -- warden's side ----------------------------------------------------------------------

    async def _read(self) -> None:
        try:
            async for data in self.ws:
                self.last_rx = time.monotonic()
                await self._on_frame(data, time.monotonic_ns())
        except ConnectionClosed:
            raise _Ended(None) from None
        except ProtocolViolation as error:
            raise _Ended(error.reason, error.detail) from None
        raise _Ended(None)

    async def _heartbeat(self) -> None:
        for seq in itertools.count(1):
            await asyncio.sleep(HEARTBEAT_INTERVAL_S)
            if time.monotonic() - self.last_rx > HEARTBEAT_TIMEOUT_S:
                raise _Ended(ByeReason.HEARTBEAT_TIMEOUT, "warden silent")
            await self._send(encode(Heartbeat(seq=seq, t_send=time.monotonic_ns())))

    async def _on_frame(self, data: bytes | str, t: int) -> None:
        frame = decode_frame(data)
        kind = message_type(frame, self.version)
        if kind in (MessageType.CHUNK, MessageType.OFFER, MessageType.CLOCK_PONG):
            raise ProtocolViolation(f"a client does not send {kind}")
        message: Message = decode_body(frame, kind)
        if isinstance(message, ClockPing):
            await self._send(encode(ClockPong(seq=message.seq, t0=message.t0, t_server=t)))
        elif isinstance(message, Hello):
            await self._on_hello(message)
        elif isinstance(message, Decision):
            self._on_decision(message)
        elif isinstance(message, ClockReport):
            self.client_offset = message.offset
        elif isinstance(message, Observation):
            self._on_observation(message, t)
        elif isinstance(message, Bye):
            raise _Ended(None)

    async def _on_hello(self, hello: Hello) -> None:
        if self.hello is not None:
            raise ProtocolViolation("a second hello on one connection")
        ours = PROTOCOL_RANGE
        if max(hello.protocol[0], ours[0]) > min(hello.protocol[1], ours[1]):
            raise ProtocolViolation(f"warden speaks {hello.protocol}, the sidecar {ours}",
                                    ByeReason.UNSUPPORTED_VERSION)
        self.hello = hello
        self.offer = self.sidecar.offer(hello.hello.queue_epoch)
        await self._send(encode(Offer(server_id=self.config.offer.server_id, offer=self.offer)))

    def _on_decision(self, message: Decision) -> None:
        if self.hello is None or self.offer is None or self.version is not None:
            raise ProtocolViolation("a decision without an offer, or a second one")
        decision = message.decision
        if decision.decision is not HandshakeVerdict.ACCEPT:
            raise _Ended(None, f"warden rejected the offer: {', '.join(decision.reasons)}")
        if decision.protocol is None:
            raise ProtocolViolation("an ACCEPT without a protocol version")
        own = fingerprint(self.hello.hello, self.offer, decision.protocol)
        if own != decision.fingerprint:
            raise ProtocolViolation(f"the sidecar computed {own}",
                                    ByeReason.FINGERPRINT_MISMATCH)
        self.version = decision.protocol
        self.accepted.set()

    def _on_observation(self, observation: Observation, t: int) -> None:
        if self.version is None:
            raise ProtocolViolation("an observation before an accepted handshake")
        q = payload_vector(observation.q, self.config.action_dim)
        try:
            pixels = check_images(observation, self.cameras, self.version)
        except ImageProblem as problem:
            raise ProtocolViolation(str(problem)) from None
        sent = Sent(observation, q, next(self.timesteps), first_time(observation), t)
        raw = lerobot_observation(self.config, q, pixels)
        self.stats.observations += 1
        if self.pending is not None:
            self.stats.superseded += 1
        self.pending = (sent, pickles.dumps(pickles.TimedObservation(
            sent.timestamp, sent.timestep, raw, must_go=True)))
        self.wake.set()

    # -- LeRobot's side ---------------------------------------------------------------------

    async def _serve_policy(self) -> None:
        await self.accepted.wait()
        try:
            async with LeRobotLink(self.config.lerobot) as link:
                started = time.perf_counter()
                await link.prepare(self.sidecar.setup)
                self.stats.prepare_s.append(time.perf_counter() - started)
                log.info("LeRobot policy ready after %.2f s", self.stats.prepare_s[-1])
                while True:
                    await self.wake.wait()
                    self.wake.clear()
                    if self.pending is not None:
                        (sent, pickled), self.pending = self.pending, None
                        await self._infer(link, sent, pickled)
        except LinkLost as error:
            raise _Ended(ByeReason.SESSION_ENDED, f"LeRobot: {error}") from None

    async def _infer(self, link: LeRobotLink, sent: Sent, pickled: bytes) -> None:
        t_start = time.monotonic_ns()
        data = await link.infer(pickled)
        t_end = time.monotonic_ns()
        self.stats.inferences += 1
        self.stats.inference_s.append((t_end - t_start) / 1e9)
        if not data:
            self.stats.empty_replies += 1
            log.warning("observation %s: LeRobot answered Empty (its queue timed out or its "
                        "inference raised: its log says which)", sent.observation.observation_id)
            return
        try:  # on a thread: the websocket's heartbeats go on while a large reply is read
            actions = reply_actions(self.config, sent, await asyncio.to_thread(read_reply, data))
        except (ReplyRefused, ReplyMismatch) as error:
            self.stats.replies_refused += 1
            self.stats.last_refusal = str(error)[:300]
            log.error("observation %s: reply refused: %s", sent.observation.observation_id,
                      self.stats.last_refusal)
            return
        await self._send(chunk_frame(self._source(), self._proposal(sent, actions, t_start,
                                                                     t_end)))
        self.stats.chunks_sent += 1
        log.info("observation %s: %d actions in %.1f ms", sent.observation.observation_id,
                 len(actions), (t_end - t_start) / 1e6)

    def _source(self) -> ChunkSource:
        if self.hello is None or self.offer is None:
            raise RuntimeError("no chunk before the handshake")
        hello, offer = self.hello.hello, self.offer
        return ChunkSource(
            policy_checkpoint=offer.policy_checkpoint, config_hash=offer.config_hash,
            skill=hello.skill, skill_version=hello.skill_version,
            controller_mode=hello.controller_mode, calibration_epoch=hello.calibration_epoch,
            action_units=offer.action_units, action_frame=offer.action_frame,
            action_dt_ns=round(1e9 / self.config.lerobot.fps), max_observation_age_ns=None,
            max_action_age_ns=None, clock_domain="client", fallback_id=None,
        )

    def _proposal(self, sent: Sent, actions: np.ndarray, t_start: int, t_end: int) -> Proposal:
        observation = sent.observation
        epoch = observation.queue_epoch
        sequence = next(self.sequences.setdefault(epoch, itertools.count(1)))
        return Proposal(
            chunk_id=f"lerobot-e{epoch}-s{sequence}", sequence=sequence, queue_epoch=epoch,
            task_phase=observation.task_phase, observation_id=observation.observation_id,
            observed_q=sent.q, actions=actions,
            first_action_time=sent.t_first, observation_event_time=observation.t_event,
            observation_arrival_time=self._to_client(sent.t_arrival),
            inference_start=self._to_client(t_start), inference_end=self._to_client(t_end),
            server_send=self._to_client(time.monotonic_ns()),
        )

    def _to_client(self, t_sidecar: int) -> int | None:
        """A sidecar time in warden's clock, once warden has reported the offset."""
        return None if self.client_offset is None else t_sidecar + self.client_offset

    async def _send(self, data: bytes) -> None:
        try:
            await self.ws.send(data)
        except ConnectionClosed:
            raise _Ended(None) from None
