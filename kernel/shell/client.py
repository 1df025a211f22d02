"""RobotClient: the robot side of the policy link (docs/protocol.md), one asyncio task.

The client owns the websocket and moves bytes; the session logic is the sans-I/O protocol object
(:class:`~kernel.shell.link_protocol.WardenProtocol`), which turns frames into outputs (events
for the core, frames to send, the connection's end). Every decision goes through the core,
reached through a :class:`Gateway` the shell implements; the core's typed decisions decide what
happens next (only its ``ACCEPT`` opens a session; its ``ChunkDecision`` records, from the
chunk's own step or its job's, are the admissions). Per connection: clock-sync burst, Hello,
Offer → core → Decision, then observations on request, chunks in, heartbeats both ways. Any end
of a connection feeds ``LinkEvent(down)`` first, then says goodbye and closes within a bound;
the client reconnects with bounded exponential backoff and always handshakes again, with the
epoch the core started at the link loss. A policy server this run launched is restarted when it
falls silent or stops accepting connections.

What one peer can cost is bounded (:mod:`kernel.shell.link_budget`): frames and chunks over
their rates are dropped and counted, chunks wait in a short queue for an admission slot the
control loop hands out (:mod:`kernel.shell.link_intake`), and at most so many observations are
in flight. The clock exchange is :mod:`kernel.shell.link_clock`, the per-connection state
:mod:`kernel.shell.link_connection`.

Expected failures (refused connections, closed sockets, protocol violations, silence, a
rejected handshake) end the connection cleanly and are counted. Anything else is a bug and
propagates out of :meth:`RobotClient.run` to the supervisor; cancellation always propagates.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import time

import structlog
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake

from assurance.handshake import HandshakeDecision, HandshakeOffer
from kernel import wire
from kernel.core import events as ev
from kernel.core.effects import ChunkDecision, EndSession, RequestObservation
from kernel.shell.link_budget import AdmissionPacer, RequestWindow, TokenBucket
from kernel.shell.link_clock import LinkClock
from kernel.shell.link_connection import SILENCE, Connection, LinkEnd, LinkEnded, closed
from kernel.shell.link_intake import ChunkIntake
from kernel.shell.link_protocol import (
    ChunkArrived,
    Ended,
    Feed,
    OfferArrived,
    Output,
    PongArrived,
    Send,
    WardenProtocol,
)
from kernel.shell.link_types import (
    ClientConfig,
    Gateway,
    LaunchedServer,
    LinkCounters,
    LinkState,
)
from kernel.shell.supervisor import describe
from kernel.wire import ByeReason, ClockSample, ProtocolViolation

log = structlog.get_logger("warden.link")


class RobotClient:
    def __init__(self, config: ClientConfig, gateway: Gateway, *,
                 pacer: AdmissionPacer | None = None,
                 server: LaunchedServer | None = None) -> None:
        self.config = config
        self.url = config.url
        self.counters = LinkCounters()
        self.state = LinkState.IDLE
        self.fingerprint: str | None = None
        self.protocol: int | None = None
        self._gateway = gateway
        self._server = server
        self._clock = LinkClock(config, gateway)
        self._frames = TokenBucket(config.policy.max_frames_per_s)
        self._window = RequestWindow(config.policy.max_requests_in_flight,
                                     config.policy.request_timeout_s)
        self._wanted = asyncio.Event()
        self._end = asyncio.Event()
        self._end_reason = ByeReason.SHUTDOWN
        self._stopping = False
        self._stopped = asyncio.Event()
        self._down_reported = False
        self._healthy = False
        self.link_protocol = WardenProtocol(config.client_id, config.protocol, self.counters)
        self._intake = ChunkIntake(gateway, self.counters, config.policy.max_chunks_per_s,
                                   self._window, pacer, self.link_protocol.chunk_event)
        gateway.on(RequestObservation, self._on_request)
        gateway.on(EndSession, self._on_session_end)
        gateway.on(ChunkDecision, self._on_chunk_decided)

    @property
    def clock(self) -> ClockSample | None:
        """The clock sync in force (the last burst's best sample)."""
        return self._clock.sample

    # -- the core's side ---------------------------------------------------------------------

    def request(self) -> None:
        """Send one observation as soon as a session is open (requests coalesce)."""
        self._wanted.set()

    def _on_request(self, _: RequestObservation) -> None:
        self.request()

    def _on_chunk_decided(self, decided: ChunkDecision) -> None:
        """What the core decided on a chunk this link carried (in the chunk's own step or in
        its job's): counted by the protocol."""
        if decided.admitted:
            self._healthy = True  # the session worked: the backoff starts from scratch again
        self.link_protocol.on_decision(decided, self._gateway.client_side_hello().queue_epoch)

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
                ended = await self._connect_once()
            finally:
                self._report_link(up=False)
            if self._stopping:
                break
            if self._healthy:  # the session worked: the next failure starts from scratch
                delay = self.config.backoff_initial_s
            self.state = LinkState.BACKOFF
            await self._revive(ended)
            await self._pause(delay)
            delay = min(delay * 2, self.config.backoff_max_s)
            self.counters.reconnects += 1
        self.state = LinkState.STOPPED

    async def _revive(self, ended: LinkEnd) -> None:
        """Restart a server this run launched once it stopped answering or accepting."""
        if self._server is None or ended is LinkEnd.OTHER or self._stopping:
            return
        try:
            self.url = await self._server.restart()
        except Exception as error:  # a child process that will not start: try again later
            self.counters.server_restart_failures += 1
            log.warning("policy server restart failed", detail=describe(error))
            return
        self.counters.server_restarts += 1
        log.info("policy server restarted", after=str(ended))

    # -- one connection --------------------------------------------------------------------

    async def _connect_once(self) -> LinkEnd:
        self.state = LinkState.CONNECTING
        cfg = self.config
        try:
            async with connect(
                self.url, max_size=cfg.policy.max_frame_bytes, compression=None, ping_interval=None,
                open_timeout=cfg.open_timeout_s, close_timeout=cfg.close_timeout_s, proxy=None,
            ) as ws:
                return await self._serve(ws)
        except (OSError, TimeoutError, InvalidHandshake):
            self.counters.connect_failures += 1  # nothing to close; back off and retry
            return LinkEnd.UNREACHABLE

    async def _serve(self, ws: ClientConnection) -> LinkEnd:
        self.counters.connects += 1
        self._report_link(up=True)
        self._end.clear()
        if self._stopping:
            self._end.set()
        link = Connection(ws, self.counters, time.monotonic(),
                          asyncio.get_running_loop().create_future())
        self._intake.begin()
        self.link_protocol.begin()
        ended: LinkEnded | None = None
        try:
            async with asyncio.TaskGroup() as tasks:
                tasks.create_task(self._read(link))
                tasks.create_task(self._intake.run())
                tasks.create_task(self._heartbeat(link))
                tasks.create_task(self._watch_end())
                tasks.create_task(self._open_session(link, tasks))
        except* LinkEnded as group:
            ended = group.exceptions[0]  # type: ignore[assignment]
        if ended is None:  # unreachable: every task runs until the link ends
            return LinkEnd.OTHER
        self._intake.end()
        self._report_link(up=False)  # the core first: it never waits for a goodbye
        await self._finish(link, ended)
        return LinkEnd.SILENT if ended.bye in SILENCE else LinkEnd.OTHER

    async def _finish(self, link: Connection, ended: LinkEnded) -> None:
        """Say goodbye and close, within ``close_timeout_s``; a silent peer is not waited for
        (its transport is aborted once the goodbye is written)."""
        self.state = LinkState.CLOSING
        self.counters.oversized += ended.oversized  # counted here: once per connection
        silent = ended.bye in SILENCE
        with contextlib.suppress(TimeoutError, ConnectionClosed):
            async with asyncio.timeout(self.config.close_timeout_s):
                if ended.bye is not None:
                    bye = wire.Bye(reason=ended.bye, detail=ended.detail[:120])
                    await link.ws.send(wire.encode(bye))
                    self.counters.byes_sent += 1
                if not silent:
                    code = 1002 if ended.bye is ByeReason.PROTOCOL_VIOLATION else 1000
                    await link.ws.close(code, str(ended.bye or "closed"))
        if link.ws.transport is not None:
            link.ws.transport.abort()  # no-op once closed; never waits for a silent peer

    async def _watch_end(self) -> None:
        await self._end.wait()
        raise LinkEnded(self._end_reason, "ended by the robot side")

    async def _pause(self, delay: float) -> None:
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(delay):
                await self._stopped.wait()

    # -- handshake -------------------------------------------------------------------------

    async def _open_session(self, link: Connection, tasks: asyncio.TaskGroup) -> None:
        self.state = LinkState.HANDSHAKING
        try:
            async with asyncio.timeout(self.config.handshake_timeout_s):
                await self._clock.sync(link)
                await self._carry(link, self.link_protocol.hello(
                    self._gateway.client_side_hello()))
                offer = await link.offer
        except TimeoutError as error:
            raise LinkEnded(ByeReason.HANDSHAKE_TIMEOUT, "no offer in time") from error
        await self._decide(link, offer)
        tasks.create_task(self._requests(link))
        tasks.create_task(self._clock.refresh(link))

    async def _decide(self, link: Connection, offer: HandshakeOffer) -> None:
        """The core decides; the client only carries its decision back to the server."""
        self._wanted.clear()  # requests made before this handshake are not for its session
        self._window.clear()
        protocol = self.link_protocol
        step = self._gateway.feed(protocol.handshake_event(offer, self._gateway.now_ns()))
        decision = next((record for record in step.decisions
                         if isinstance(record, HandshakeDecision)), None)
        if decision is None:
            raise RuntimeError("the core answered a handshake without a handshake decision")
        epoch = self._gateway.client_side_hello().queue_epoch
        await self._carry(link, protocol.on_decision(decision, epoch))
        link.version = decision.protocol  # the clock exchange reads it
        self.fingerprint, self.protocol = decision.fingerprint, decision.protocol
        self.state = LinkState.ACCEPTED
        await self._clock.report(link)

    # -- observations out ------------------------------------------------------------------

    async def _requests(self, link: Connection) -> None:
        window = self._window
        while True:
            await self._wanted.wait()
            if not window.open():  # enough in flight: send when one is answered or expires
                self.counters.requests_waited += 1
                while not window.open():
                    window.changed.clear()
                    with contextlib.suppress(TimeoutError):
                        async with asyncio.timeout(window.wait_s()):
                            await window.changed.wait()
            self._wanted.clear()
            await self._observe(link)
            self.counters.requests_expired = window.expired

    async def _observe(self, link: Connection) -> None:
        sample = self._gateway.capture_observation()
        t = self._gateway.now_ns()
        epoch = self._gateway.client_side_hello().queue_epoch
        for output in self.link_protocol.observe(sample, t, epoch):
            if isinstance(output, Feed) and isinstance(output.event, ev.ObservationEvent):
                self._window.sent(output.event.observation_id)
            await self._carry(link, [output])
        self.counters.observations_sent += 1

    async def _heartbeat(self, link: Connection) -> None:
        """Send a heartbeat every interval; declare the peer silent the moment it has been for
        ``heartbeat_timeout_s`` (woken at that instant, not at the next heartbeat)."""
        interval, timeout = (self.config.policy.heartbeat_interval_s,
                             self.config.policy.heartbeat_timeout_s)
        next_send = time.monotonic() + interval
        for seq in itertools.count(1):
            while (now := time.monotonic()) < next_send:
                await asyncio.sleep(min(next_send, link.last_rx + timeout) - now)
                if time.monotonic() - link.last_rx > timeout:
                    await self._declare_silence(link, timeout)
            if now - link.last_rx > 1.5 * interval:  # the peer's heartbeat (or anything) is late
                self.counters.heartbeat_misses += 1
            await link.send(wire.Heartbeat(seq=seq, t_send=self._gateway.now_ns()))
            next_send += interval

    async def _declare_silence(self, link: Connection, timeout: float) -> None:
        # After a stall of this loop, frames may sit unread: let the reader run first.
        for _ in range(3):
            await asyncio.sleep(0)
        silent = time.monotonic() - link.last_rx
        if silent > timeout:
            self.counters.link_timeouts += 1
            raise LinkEnded(ByeReason.HEARTBEAT_TIMEOUT, f"peer silent for {silent:.3f} s")

    # -- frames in -------------------------------------------------------------------------

    async def _read(self, link: Connection) -> None:
        try:
            async for data in link.ws:
                link.last_rx = time.monotonic()
                self.counters.frames_in += 1
                self.counters.bytes_in += len(data)
                if not self._frames.take():
                    self.counters.frames_dropped += 1  # over the frame rate: not even decoded
                    continue
                self._apply(link, self.link_protocol.receive_frame(
                    data, self._gateway.now_ns()))
        except ConnectionClosed as error:
            raise closed(error) from error
        except ProtocolViolation as error:
            raise link.violation(error) from error
        raise LinkEnded(None, "closed by the server")

    def _apply(self, link: Connection, outputs: list[Output]) -> None:
        """Carry out what the protocol made of a frame (nothing here sends)."""
        for output in outputs:
            if isinstance(output, ChunkArrived):
                self._intake.put(output.frame)
            elif isinstance(output, PongArrived):
                self._clock.on_pong(link, output.pong, output.t_receive)
            elif isinstance(output, OfferArrived):
                if not link.offer.done():
                    link.offer.set_result(output.offer)
            elif isinstance(output, Ended):
                raise LinkEnded(output.bye, output.detail)
            elif isinstance(output, Feed):
                self._gateway.feed(output.event)

    async def _carry(self, link: Connection, outputs: list[Output]) -> None:
        """Carry out what the protocol made of the core's side: frames sent, events fed."""
        for output in outputs:
            if isinstance(output, Send):
                await link.send_data(output.data)
            elif isinstance(output, Feed):
                self._gateway.feed(output.event)
            elif isinstance(output, Ended):
                raise LinkEnded(output.bye, output.detail)

    # -- helpers ---------------------------------------------------------------------------

    def _report_link(self, up: bool) -> None:
        if up or not self._down_reported:  # one "down" per loss, not one per failed attempt
            self._down_reported = not up
            status = ev.LinkStatus.UP if up else ev.LinkStatus.DOWN
            self._gateway.feed(ev.LinkEvent(t=self._gateway.now_ns(), status=status))
