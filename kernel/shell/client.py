"""RobotClient: the robot side of the policy link (docs/protocol.md), one asyncio task.

The client owns the websocket and nothing else. Every decision goes through the core, reached
through a :class:`Gateway` the shell implements: the client turns frames into events
(clock sync, handshake offer, observation taken, chunk arrived, link down) and feeds them; the
core's answer decides what happens next (only its ``ACCEPT`` opens a session; its chunk lines
are the admissions). Per connection: clock-sync burst, Hello, Offer → core → Decision, then
observations on request, chunks in, heartbeats both ways. Any end of a connection feeds
``LinkEvent(down)``; the client reconnects with bounded exponential backoff and always
handshakes again, with the epoch the core started at the link loss.

Expected failures (refused connections, closed sockets, protocol violations, silence, a
rejected handshake) end the connection cleanly and are counted. Anything else is a bug and
propagates out of :meth:`RobotClient.run` to the supervisor; cancellation always propagates.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import time
from dataclasses import dataclass

import msgspec
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake

from assurance.envelope import MalformedChunk, decode_wire_chunk
from assurance.handshake import HandshakeDecision
from kernel import wire
from kernel.core import events as ev
from kernel.core.effects import EndSession, RequestObservation
from kernel.core.lines import ChunkLine, HandshakeLine
from kernel.shell.link_types import (
    ClientConfig,
    Gateway,
    LinkCounters,
    LinkState,
)
from kernel.summary import ADMITTED
from kernel.wire import ByeReason, ClockSample, Frame, Message, MessageType, ProtocolViolation

_CLOSE_TOO_BIG = 1009


class _LinkEnded(Exception):
    """This connection is over; ``bye`` is what to tell the peer (None: nothing to say)."""

    def __init__(self, bye: ByeReason | None, detail: str, oversized: bool = False) -> None:
        super().__init__(detail)
        self.bye = bye
        self.detail = detail
        self.oversized = oversized


@dataclass(slots=True, eq=False)
class _Link:
    """Per-connection state; a new one for every connection."""

    ws: ClientConnection
    last_rx: float
    offer: asyncio.Future[wire.Offer]
    accepted: bool = False
    version: int | None = None
    pong: asyncio.Future[tuple[wire.ClockPong, int]] | None = None
    """The answer to the one ping in flight (pings of a burst go one at a time)."""
    ping_seq: int = 0


class RobotClient:
    def __init__(self, config: ClientConfig, gateway: Gateway) -> None:
        self.config = config
        self.counters = LinkCounters()
        self.state = LinkState.IDLE
        self.fingerprint: str | None = None
        self.protocol: int | None = None
        self.clock: ClockSample | None = None
        self._gateway = gateway
        self._wanted = asyncio.Event()
        self._end = asyncio.Event()
        self._end_reason = ByeReason.SHUTDOWN
        self._stopping = False
        self._stopped = asyncio.Event()
        self._down_reported = False
        self._healthy = False
        self._observation_ids = itertools.count(1)
        gateway.on(RequestObservation, self._on_request)
        gateway.on(EndSession, self._on_session_end)

    # -- the core's side ---------------------------------------------------------------------

    def request(self) -> None:
        """Send one observation as soon as a session is open (requests coalesce)."""
        self._wanted.set()

    def _on_request(self, _: RequestObservation) -> None:
        self.request()

    def _on_session_end(self, _: EndSession) -> None:
        """The core ended the session (DEGRADED needs a new handshake): reconnect."""
        if self.state is LinkState.ACCEPTED:
            self._end_reason = ByeReason.SESSION_ENDED
            self._end.set()

    def stop(self) -> None:
        """End the session with Bye(shutdown) and make :meth:`run` return."""
        self._stopping = True
        self._end_reason = ByeReason.SHUTDOWN
        self._end.set()
        self._stopped.set()

    async def run(self) -> None:
        """Connect, serve, reconnect with backoff, until :meth:`stop` or cancellation."""
        delay = self.config.backoff_initial_s
        while not self._stopping:
            self._healthy = False
            try:
                await self._connect_once()
            finally:
                self._report_link(up=False)
            if self._stopping:
                break
            if self._healthy:  # the session worked: the next failure starts from scratch
                delay = self.config.backoff_initial_s
            self.state = LinkState.BACKOFF
            await self._pause(delay)
            delay = min(delay * 2, self.config.backoff_max_s)
            self.counters.reconnects += 1
        self.state = LinkState.STOPPED

    # -- one connection --------------------------------------------------------------------

    async def _connect_once(self) -> None:
        self.state = LinkState.CONNECTING
        cfg = self.config
        try:
            async with connect(
                cfg.url, max_size=cfg.max_frame_bytes, compression=None, ping_interval=None,
                open_timeout=cfg.open_timeout_s, close_timeout=cfg.close_timeout_s, proxy=None,
            ) as ws:
                await self._serve(ws)
        except (OSError, TimeoutError, InvalidHandshake):
            self.counters.connect_failures += 1  # nothing to close; back off and retry

    async def _serve(self, ws: ClientConnection) -> None:
        self.counters.connects += 1
        self._report_link(up=True)
        self._end.clear()
        if self._stopping:
            self._end.set()
        link = _Link(ws, time.monotonic(), asyncio.get_running_loop().create_future())
        try:
            async with asyncio.TaskGroup() as tasks:
                tasks.create_task(self._read(link))
                tasks.create_task(self._heartbeat(link))
                tasks.create_task(self._watch_end())
                tasks.create_task(self._open_session(link, tasks))
        except* _LinkEnded as group:
            await self._finish(link, group.exceptions[0])  # type: ignore[arg-type]

    async def _finish(self, link: _Link, ended: _LinkEnded) -> None:
        self.state = LinkState.CLOSING
        self.counters.oversized += ended.oversized  # counted here: once per connection
        if ended.bye is not None:
            with contextlib.suppress(ConnectionClosed):
                bye = wire.Bye(reason=ended.bye, detail=ended.detail[:120])
                await link.ws.send(wire.encode(bye))
                self.counters.byes_sent += 1
        code = 1002 if ended.bye is ByeReason.PROTOCOL_VIOLATION else 1000
        await link.ws.close(code, str(ended.bye or "closed"))

    async def _watch_end(self) -> None:
        await self._end.wait()
        raise _LinkEnded(self._end_reason, "ended by the robot side")

    async def _pause(self, delay: float) -> None:
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(delay):
                await self._stopped.wait()

    # -- handshake -------------------------------------------------------------------------

    async def _open_session(self, link: _Link, tasks: asyncio.TaskGroup) -> None:
        self.state = LinkState.HANDSHAKING
        try:
            async with asyncio.timeout(self.config.handshake_timeout_s):
                await self._sync_clock(link)
                await self._send(link, wire.Hello(client_id=self.config.client_id,
                                                  protocol=self.config.protocol,
                                                  hello=self._gateway.client_side_hello()))
                offer = await link.offer
        except TimeoutError as error:
            raise _LinkEnded(ByeReason.HANDSHAKE_TIMEOUT, "no offer in time") from error
        await self._decide(link, offer)
        tasks.create_task(self._requests(link))
        tasks.create_task(self._refresh_clock(link))

    async def _decide(self, link: _Link, offer: wire.Offer) -> None:
        """The core decides; the client only carries its decision back to the server."""
        self._wanted.clear()  # requests made before this handshake are not for its session
        step = self._gateway.feed(ev.HandshakeEvent(t=self._gateway.now_ns(),
                                                    offer=msgspec.to_builtins(offer.offer)))
        verdict = next((line for line in step.lines if isinstance(line, HandshakeLine)), None)
        if verdict is None:
            raise RuntimeError("the core answered a handshake without a handshake line")
        decision = HandshakeDecision(decision=verdict.decision, fingerprint=verdict.fingerprint,
                                     reasons=tuple(verdict.reasons), protocol=verdict.protocol)
        epoch = self._gateway.client_side_hello().queue_epoch
        await self._send(link, wire.Decision(decision=decision, queue_epoch=epoch))
        if verdict.decision != "ACCEPT" or verdict.protocol is None:
            self.counters.handshakes_rejected += 1
            raise _LinkEnded(ByeReason.HANDSHAKE_REJECTED, ",".join(verdict.reasons))
        self.counters.handshakes_accepted += 1
        link.accepted, link.version = True, verdict.protocol
        self.fingerprint, self.protocol = verdict.fingerprint, verdict.protocol
        self.state = LinkState.ACCEPTED
        await self._report_clock(link)

    # -- clock -----------------------------------------------------------------------------

    async def _sync_clock(self, link: _Link) -> None:
        samples = [await self._ping(link) for _ in range(self.config.clock_burst)]
        best = wire.best_sample(samples)
        if best is None:
            raise _LinkEnded(ByeReason.PROTOCOL_VIOLATION, "no usable clock sample")
        self.clock = best
        self.counters.clock_syncs += 1
        self._gateway.feed(ev.ClockSyncEvent(
            t=self._gateway.now_ns(), domain=wire.SERVER_CLOCK_DOMAIN, offset=best.offset,
            round_trip=best.round_trip))

    async def _report_clock(self, link: _Link) -> None:
        if link.version is not None and link.version >= 2 and self.clock is not None:
            await self._send(link, wire.ClockReport(offset=self.clock.offset,
                                                    round_trip=self.clock.round_trip))

    async def _ping(self, link: _Link) -> ClockSample:
        link.ping_seq += 1
        link.pong = answer = asyncio.get_running_loop().create_future()
        t0 = self._gateway.now_ns()
        try:
            await self._send(link, wire.ClockPing(seq=link.ping_seq, t0=t0))
            async with asyncio.timeout(self.config.clock_ping_timeout_s):
                pong, t1 = await answer
            sample = wire.clock_sample(t0, pong, t1)
        except TimeoutError as error:
            raise _LinkEnded(ByeReason.CLOCK_TIMEOUT, "clock ping unanswered") from error
        except ProtocolViolation as error:  # an implausible clock: never fed to the core
            raise self._violation(error) from error
        finally:
            link.pong = None
        self.counters.clock_round_trips += 1
        return sample

    async def _refresh_clock(self, link: _Link) -> None:
        while True:
            await asyncio.sleep(self.config.clock_refresh_s)
            await self._sync_clock(link)
            await self._report_clock(link)

    # -- traffic ---------------------------------------------------------------------------

    async def _requests(self, link: _Link) -> None:
        while True:
            await self._wanted.wait()
            self._wanted.clear()
            sample = self._gateway.capture_observation()
            t = self._gateway.now_ns()
            observation_id = f"{self.config.client_id}/{next(self._observation_ids)}"
            self._gateway.feed(ev.ObservationEvent(t=t, observation_id=observation_id))
            epoch = self._gateway.client_side_hello().queue_epoch
            await self._send(link, wire.Observation(
                observation_id=observation_id, t_event=t, queue_epoch=epoch,
                task_phase=str(sample.task_phase), q=wire.vector_payload(sample.q),
                qd=wire.optional_payload(sample.qd), wrench=wire.optional_payload(sample.wrench),
                gripper=sample.gripper))
            self.counters.observations_sent += 1

    async def _heartbeat(self, link: _Link) -> None:
        interval, timeout = self.config.heartbeat_interval_s, self.config.heartbeat_timeout_s
        for seq in itertools.count(1):
            await asyncio.sleep(interval)
            silent = time.monotonic() - link.last_rx
            if silent > 1.5 * interval:  # the peer's heartbeat (or anything) is overdue
                self.counters.heartbeat_misses += 1
            if silent > timeout:
                self.counters.link_timeouts += 1
                raise _LinkEnded(ByeReason.HEARTBEAT_TIMEOUT, f"peer silent for {silent:.3f} s")
            await self._send(link, wire.Heartbeat(seq=seq, t_send=self._gateway.now_ns()))

    async def _read(self, link: _Link) -> None:
        try:
            async for data in link.ws:
                t_receive = self._gateway.now_ns()
                link.last_rx = time.monotonic()
                self.counters.frames_in += 1
                self.counters.bytes_in += len(data)
                self._dispatch(link, data, t_receive)
        except ConnectionClosed as error:
            raise self._closed(error) from error
        except ProtocolViolation as error:
            raise self._violation(error) from error
        raise _LinkEnded(None, "closed by the server")

    def _dispatch(self, link: _Link, data: bytes | str, t_receive: int) -> None:
        frame = wire.decode_frame(data)
        kind = wire.message_type(frame, link.version)
        if kind is MessageType.CHUNK:
            self._on_chunk(link, frame, t_receive)
            return
        message = wire.decode_body(frame, kind)
        if isinstance(message, wire.ClockPong):
            self._on_pong(link, message, t_receive)
        elif isinstance(message, wire.Offer) and not link.offer.done():
            link.offer.set_result(message)
        elif isinstance(message, wire.Bye):
            self.counters.byes_received += 1
            raise _LinkEnded(None, f"server said bye: {message.reason}")
        elif not isinstance(message, wire.Heartbeat):
            raise ProtocolViolation(f"unexpected {kind} from the server")

    def _on_chunk(self, link: _Link, frame: Frame, t_receive: int) -> None:
        if not link.accepted:  # never let a chunk reach the core outside an accepted session
            raise ProtocolViolation("chunk before the session was accepted")
        self.counters.chunks_in += 1
        chunk = decode_wire_chunk(frame.body, t_receive)
        if isinstance(chunk, MalformedChunk):
            self.counters.malformed += 1
        for line in self._gateway.feed(ev.ChunkEvent(t_receive, chunk, bytes(frame.body))).lines:
            if isinstance(line, ChunkLine):
                admitted = line.decision in ADMITTED
                self._healthy |= admitted
                self.counters.chunks_admitted += admitted
                self.counters.chunks_refused += not admitted

    def _on_pong(self, link: _Link, pong: wire.ClockPong, t_receive: int) -> None:
        # a pong for a ping that already timed out carries no usable sample: dropped
        if link.pong is not None and pong.seq == link.ping_seq and not link.pong.done():
            link.pong.set_result((pong, t_receive))

    # -- helpers ---------------------------------------------------------------------------

    async def _send(self, link: _Link, message: Message) -> None:
        data = wire.encode(message)
        try:
            await link.ws.send(data)
        except ConnectionClosed as error:
            raise self._closed(error) from error
        self.counters.frames_out += 1
        self.counters.bytes_out += len(data)

    def _violation(self, error: ProtocolViolation) -> _LinkEnded:
        self.counters.protocol_violations += 1
        return _LinkEnded(error.reason, error.detail)

    @staticmethod
    def _closed(error: ConnectionClosed) -> _LinkEnded:
        if error.sent is not None and error.sent.code == _CLOSE_TOO_BIG:
            return _LinkEnded(None, "frame over the size limit", oversized=True)
        return _LinkEnded(None, f"connection closed ({error})")

    def _report_link(self, up: bool) -> None:
        if up or not self._down_reported:  # one "down" per loss, not one per failed attempt
            self._down_reported = not up
            status = "up" if up else "down"
            self._gateway.feed(ev.LinkEvent(t=self._gateway.now_ns(), status=status))


