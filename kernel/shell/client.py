"""RobotClient: the robot side of the policy link (docs/protocol.md), one asyncio task.

The client owns the websocket and only moves bytes: it reads frames into the sans-I/O protocol
object (:class:`~kernel.shell.link_protocol.WardenProtocol`) with the instant it read them,
writes the frames it returns, sleeps until its next deadline and then hands it that instant,
and carries out the rest of what it returns (events for the core, the connection's end). Every
timing decision (heartbeats, silence, the handshake's and pings' timeouts, the clock exchange,
the rates and the window of requests in flight) is the protocol object's. Every decision about
a session goes through the core, reached through a :class:`Gateway` the shell implements; the
core's typed decisions decide what happens next (only its ``ACCEPT`` opens a session; its
``ChunkDecision`` records, from the chunk's own step or its job's, are the admissions). Per
connection: clock-sync burst, Hello, Offer → core → Decision, then observations on request,
chunks in, heartbeats both ways. Any end of a connection feeds ``LinkEvent(down)`` first, then
says goodbye and closes within a bound; the client reconnects with bounded exponential backoff
and always handshakes again, with the epoch the core started at the link loss. A policy server
this run launched is restarted when it falls silent or stops accepting connections.

Chunks wait in the protocol's short queue for an admission slot the control loop hands out
(:mod:`kernel.shell.link_intake`); the websocket is :mod:`kernel.shell.link_connection`.

Expected failures (refused connections, closed sockets, protocol violations, silence, a
rejected handshake) end the connection cleanly and are counted. Anything else is a bug and
propagates out of :meth:`RobotClient.run` to the supervisor; cancellation always propagates.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
from collections import deque

import structlog
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake

from assurance.handshake import HandshakeDecision, HandshakeOffer
from kernel import wire
from kernel.core import events as ev
from kernel.core.effects import ChunkDecision, EndSession, RequestObservation
from kernel.shell.link_budget import AdmissionPacer
from kernel.shell.link_connection import SILENCE, Connection, LinkEnd, LinkEnded, closed
from kernel.shell.link_credentials import foreign_server, subprotocols
from kernel.shell.link_intake import ChunkIntake
from kernel.shell.link_openpi import OpenpiLink, OpenpiProtocol
from kernel.shell.link_protocol import (
    ChunksWaiting,
    Ended,
    Feed,
    HelloDue,
    LinkProtocol,
    ObservationDue,
    OfferArrived,
    Output,
    Send,
    WardenProtocol,
)
from kernel.shell.link_security import why_refused
from kernel.shell.link_settings import PolicyProtocol
from kernel.shell.link_types import (
    CameraFrames,
    ClientConfig,
    Gateway,
    LaunchedServer,
    LinkCounters,
    LinkState,
)
from kernel.shell.supervisor import describe
from kernel.wire import ByeReason, ClockSample

log = structlog.get_logger("warden.link")


class RobotClient:
    def __init__(self, config: ClientConfig, gateway: Gateway, *,
                 pacer: AdmissionPacer | None = None,
                 server: LaunchedServer | None = None,
                 cameras: CameraFrames | None = None) -> None:
        self.config = config
        self._cameras = cameras
        self.url = config.url
        self.counters = LinkCounters()
        self.state = LinkState.IDLE
        self._gateway = gateway
        self._server = server
        self.link_protocol = _protocol_for(config, self.counters)
        self._intake = ChunkIntake(self.link_protocol, self.counters, pacer, gateway.now_ns,
                                   self._apply)
        self._wanted = asyncio.Event()
        self._outbox: deque[bytes] = deque()
        self._outbox_ready = asyncio.Event()
        self._rearm = asyncio.Event()
        self._armed_ns: int | None = None
        """The deadline the timer task sleeps until (None: none)."""
        self._end = asyncio.Event()
        self._ending: LinkEnded | None = None
        self._stopping = False
        self._stopped = asyncio.Event()
        self._down_reported = False
        self._healthy = False
        self.refusal: str | None = None
        """Why the last connection attempt was refused for good (None: none was)."""
        gateway.on(RequestObservation, self._on_request)
        gateway.on(EndSession, self._on_session_end)
        gateway.on(ChunkDecision, self._on_chunk_decided)

    @property
    def clock(self) -> ClockSample | None:
        """The clock sync in force (the last burst's best sample)."""
        return self.link_protocol.clock

    @property
    def fingerprint(self) -> str | None:
        """The last accepted session's fingerprint."""
        return self.link_protocol.fingerprint

    @property
    def protocol(self) -> int | None:
        """The negotiated protocol version (held by the protocol object only)."""
        return self.link_protocol.version

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
        self._apply(self.link_protocol.on_decision(
            decided, self._gateway.client_side_hello().queue_epoch, self._gateway.now_ns()))

    def _on_session_end(self, _: EndSession) -> None:
        """The core ended the session (DEGRADED needs a new handshake): reconnect."""
        if self.state is LinkState.ACCEPTED:
            self._end_with(LinkEnded(ByeReason.SESSION_ENDED, "ended by the robot side"))

    def stop(self) -> None:
        """End the session with Bye(shutdown) and make :meth:`run` return."""
        self._stopping = True
        self._ending = None
        self._end_with(LinkEnded(ByeReason.SHUTDOWN, "ended by the robot side"))
        self._stopped.set()

    def _end_with(self, ended: LinkEnded) -> None:
        """End this connection (the first reason given is the one told the peer)."""
        if self._ending is None:
            self._ending = ended
        self._end.set()

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
        protocol, security = cfg.policy.protocol, cfg.security
        tls = {} if security.tls is None else {"ssl": security.tls,
                                               "server_hostname": security.server_name}
        try:
            async with connect(
                self.url, max_size=cfg.policy.max_frame_bytes, compression=None, ping_interval=None,
                open_timeout=cfg.open_timeout_s, close_timeout=cfg.close_timeout_s, proxy=None,
                additional_headers=security.headers(protocol),
                subprotocols=subprotocols(protocol), **tls,  # type: ignore[arg-type]
            ) as ws:
                foreign = foreign_server(protocol, ws.subprotocol)
                if foreign is None:
                    return await self._serve(ws)
                await ws.close(1002, "no common subprotocol")
                self._refused(foreign)
                return LinkEnd.OTHER  # the server answers: restarting it would not help
        except (OSError, TimeoutError, InvalidHandshake) as error:
            self.counters.connect_failures += 1  # nothing to close; back off and retry
            refused = why_refused(error, tls=security.tls is not None)
            if refused is None:
                return LinkEnd.UNREACHABLE
            self._refused(refused)
            return LinkEnd.OTHER

    def _refused(self, why: str) -> None:
        """A refusal retrying will not mend: counted, and logged when it changes (the client
        still retries with backoff: an operator may be fixing the server's side)."""
        self.counters.connects_refused += 1
        if why != self.refusal:
            log.warning("policy server connection refused", detail=why)
        self.refusal = why

    async def _serve(self, ws: ClientConnection) -> LinkEnd:
        self.counters.connects += 1
        self._report_link(up=True)
        self._end.clear()
        self._ending, self._armed_ns = None, None
        if self._stopping:
            self._end_with(LinkEnded(ByeReason.SHUTDOWN, "ended by the robot side"))
        link = Connection(ws, self.counters)
        self._outbox.clear()
        self.state = LinkState.HANDSHAKING
        self._apply(self.link_protocol.connect(self._gateway.now_ns()))
        ended: LinkEnded | None = None
        try:
            async with asyncio.TaskGroup() as tasks:
                for job in (self._read(link), self._write(link), self._timers(),
                            self._intake.run(), self._requests(), self._watch_end()):
                    tasks.create_task(job)
        except* LinkEnded as group:
            ended = group.exceptions[0]  # type: ignore[assignment]
        self.link_protocol.close()  # nothing queued on this connection is ever fed
        if ended is None:  # unreachable: every task runs until the link ends
            return LinkEnd.OTHER
        self._report_link(up=False)  # the core first: it never waits for a goodbye
        await self._finish(link, ended)
        return LinkEnd.SILENT if ended.bye in SILENCE else LinkEnd.OTHER

    async def _finish(self, link: Connection, ended: LinkEnded) -> None:
        """Send what the protocol said before the end (a refused handshake's decision), say
        goodbye and close, within ``close_timeout_s``; a silent peer is not waited for (its
        transport is aborted once the goodbye is written)."""
        self.state = LinkState.CLOSING
        self.counters.oversized += ended.oversized  # counted here: once per connection
        silent = ended.bye in SILENCE
        with contextlib.suppress(TimeoutError, ConnectionClosed, LinkEnded):
            async with asyncio.timeout(self.config.close_timeout_s):
                while self._outbox:
                    await link.send_data(self._outbox.popleft())
                if ended.bye is not None and self.link_protocol.says_goodbye:
                    bye = wire.Bye(reason=ended.bye, detail=ended.detail[:120])
                    await link.ws.send(wire.encode(bye))
                    self.counters.byes_sent += 1
                if not silent:
                    code = 1002 if ended.bye is ByeReason.PROTOCOL_VIOLATION else 1000
                    await link.ws.close(code, str(ended.bye or "closed"))
        self._outbox.clear()
        if link.ws.transport is not None:
            link.ws.transport.abort()  # no-op once closed; never waits for a silent peer

    async def _watch_end(self) -> None:
        await self._end.wait()
        raise self._ending or LinkEnded(ByeReason.SHUTDOWN, "ended by the robot side")

    async def _pause(self, delay: float) -> None:
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(delay):
                await self._stopped.wait()

    # -- bytes and time through the protocol -----------------------------------------------

    async def _read(self, link: Connection) -> None:
        try:
            async for data in link.ws:
                self._apply(self.link_protocol.receive_frame(data, self._gateway.now_ns()))
        except ConnectionClosed as error:
            raise closed(error) from error
        raise LinkEnded(None, "closed by the server")

    async def _write(self, link: Connection) -> None:
        while True:
            while not self._outbox:
                self._outbox_ready.clear()
                await self._outbox_ready.wait()
            await link.send_data(self._outbox.popleft())

    async def _timers(self) -> None:
        """Sleep until the protocol's next deadline (or an earlier one it sets), then hand it
        the instant: it decides what is due (heartbeats, pings, the end of a silent peer)."""
        protocol = self.link_protocol
        while True:
            self._rearm.clear()
            self._armed_ns = deadline = protocol.next_deadline()
            if deadline is None:
                await self._rearm.wait()
                continue
            delay_s = (deadline - self._gateway.now_ns()) / 1e9
            if delay_s > 0:
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(delay_s):
                        await self._rearm.wait()
                continue
            # After a stall of this loop, frames may sit unread: let the reader run first.
            for _ in range(3):
                await asyncio.sleep(0)
            self._apply(protocol.timeout(self._gateway.now_ns()))

    async def _requests(self) -> None:
        while True:
            await self._wanted.wait()
            self._wanted.clear()
            if self._cameras is not None:  # a rendered camera draws the cell as it is now
                await self._cameras.fresh(self._gateway.now_ns(), self._gateway.now_ns)
            self._apply(self.link_protocol.request(self._gateway.now_ns()))

    def _apply(self, outputs: list[Output]) -> None:
        """Carry out what the protocol returned (frames go to the writer; nothing here
        waits)."""
        protocol, gateway = self.link_protocol, self._gateway
        for output in outputs:
            if isinstance(output, Send):
                self._outbox.append(output.data)
                self._outbox_ready.set()
            elif isinstance(output, Feed):
                gateway.feed(output.event)
            elif isinstance(output, HelloDue):
                self._apply(protocol.hello(gateway.client_side_hello(), gateway.now_ns()))
            elif isinstance(output, OfferArrived):
                self._decide(output.offer)
            elif isinstance(output, ChunksWaiting):
                self._intake.wake()
            elif isinstance(output, ObservationDue):
                self._observe(output)
            elif isinstance(output, Ended):
                self._end_with(LinkEnded(output.bye, output.detail))
        deadline = protocol.next_deadline()
        if deadline is not None and (self._armed_ns is None or deadline < self._armed_ns):
            self._rearm.set()  # the timer task sleeps until a later instant: wake it

    def _observe(self, due: ObservationDue) -> None:
        """Capture the robot and its cameras, and send the observation; with a camera that has
        no fresh frame nothing goes out (the core requests again once it is back)."""
        gateway = self._gateway
        now = gateway.now_ns()
        images = self._cameras.images(now) if self._cameras is not None else ()
        if images is None:
            return
        sample = dataclasses.replace(gateway.capture_observation(due.prefix_grid_ns, now),
                                     images=images)
        self._apply(self.link_protocol.observe(sample, now,
                                               gateway.client_side_hello().queue_epoch))

    def _decide(self, offer: HandshakeOffer) -> None:
        """The core decides; the client only carries its decision back to the server."""
        self._wanted.clear()  # requests made before this handshake are not for its session
        protocol, gateway = self.link_protocol, self._gateway
        step = gateway.feed(protocol.handshake_event(offer, gateway.now_ns()))
        decision = next((record for record in step.decisions
                         if isinstance(record, HandshakeDecision)), None)
        if decision is None:
            raise RuntimeError("the core answered a handshake without a handshake decision")
        outputs = protocol.on_decision(decision, gateway.client_side_hello().queue_epoch,
                                       gateway.now_ns())
        if protocol.accepted:
            self.state = LinkState.ACCEPTED
        else:  # what the server offered, so that an operator can see what to allow or fix
            log.warning("policy handshake refused", reasons=list(decision.reasons),
                        policy_checkpoint=offer.policy_checkpoint, config_hash=offer.config_hash)
        self._apply(outputs)

    # -- helpers ---------------------------------------------------------------------------

    def _report_link(self, up: bool) -> None:
        if up or not self._down_reported:  # one "down" per loss, not one per failed attempt
            self._down_reported = not up
            status = ev.LinkStatus.UP if up else ev.LinkStatus.DOWN
            self._gateway.feed(ev.LinkEvent(t=self._gateway.now_ns(), status=status))


def _protocol_for(config: ClientConfig, counters: LinkCounters) -> LinkProtocol:
    """The protocol object of what the policy server speaks (``[policy] protocol``)."""
    if config.policy.protocol is PolicyProtocol.OPENPI:
        return OpenpiProtocol(config.client_id, OpenpiLink.of(config.policy), counters,
                              config.timing)
    return WardenProtocol(config.client_id, config.wire_versions, counters, config.timing)
