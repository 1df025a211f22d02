"""The policy link's timing, decided by the protocol object alone on the times it is handed:
heartbeats, the peer's silence, the handshake's and pings' timeouts, the clock exchange, the
rates and the window of requests in flight (kernel/shell/link_protocol.py). No socket, task or
clock: every instant is an argument."""

from __future__ import annotations

import dataclasses

import msgspec
import numpy as np
from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, precondition, rule

from kernel import wire
from kernel.core.events import ClockSyncEvent
from kernel.shell.link_protocol import (
    ChunksWaiting,
    Ended,
    Feed,
    HelloDue,
    ObservationDue,
    OfferArrived,
    Output,
    Send,
    WardenProtocol,
)
from kernel.shell.link_types import LinkCounters, RobotSample
from kernel.wire import ByeReason
from tests.core.test_handshake import HELLO
from tests.shell.test_link_protocol import ACCEPT, MS, OFFERED, TIMING, _accepted, _chunk_frame

SYNCED = dataclasses.replace(TIMING, clock_burst=3)
SAMPLE = RobotSample(q=np.zeros(6), task_phase="FREE_SPACE")
OFFER_FRAME = wire.encode(wire.Offer(server_id="s", offer=OFFERED))


def _messages(outputs: list[Output]) -> list[wire.Message]:
    frames = [wire.decode_frame(o.data) for o in outputs if isinstance(o, Send)]
    return [wire.decode_body(frame, wire.message_type(frame)) for frame in frames]


def _heartbeat(t: int) -> bytes:
    return wire.encode(wire.Heartbeat(seq=1, t_send=t))


def _pong(ping: wire.Message, t_server: int) -> bytes:
    assert isinstance(ping, wire.ClockPing)
    return wire.encode(wire.ClockPong(seq=ping.seq, t0=ping.t0, t_server=t_server))


def test_heartbeats_go_out_on_schedule_and_a_late_peer_is_a_miss() -> None:
    protocol = _accepted()  # connected at 0
    assert protocol.next_deadline() == 100 * MS
    assert protocol.timeout(100 * MS - 1) == []
    protocol.receive_frame(_heartbeat(0), 90 * MS)
    assert _messages(protocol.timeout(100 * MS)) == [wire.Heartbeat(seq=1, t_send=100 * MS)]
    assert protocol.next_deadline() == 200 * MS
    assert protocol.counters.heartbeat_misses == 0
    (second,) = _messages(protocol.timeout(250 * MS))  # nothing since 90 ms: 160 ms > 1.5 x
    assert second == wire.Heartbeat(seq=2, t_send=250 * MS)
    assert protocol.counters.heartbeat_misses == 1
    # a stalled caller catches up: every heartbeat due is sent, none skipped
    protocol.receive_frame(_heartbeat(0), 420 * MS)
    assert [m.seq for m in _messages(protocol.timeout(420 * MS))] == [3, 4]


def test_a_silent_peer_ends_the_link_at_exactly_the_bound_and_once() -> None:
    protocol = _accepted()
    protocol.receive_frame(_heartbeat(0), 40 * MS)
    assert protocol.next_deadline() == 100 * MS
    for t in (100 * MS, 200 * MS, 300 * MS):
        assert all(isinstance(o, Send) for o in protocol.timeout(t))
    assert protocol.next_deadline() == 390 * MS  # the bound, before the next heartbeat
    assert protocol.timeout(390 * MS - 1) == []
    assert protocol.timeout(390 * MS) == [Ended(ByeReason.HEARTBEAT_TIMEOUT,
                                                 "peer silent for 0.350 s")]
    assert protocol.counters.link_timeouts == 1
    assert protocol.next_deadline() is None
    assert protocol.timeout(400 * MS) == protocol.receive_frame(_heartbeat(0), 400 * MS) == []
    assert protocol.counters.link_timeouts == 1


def test_any_frame_keeps_the_peer_alive_even_one_dropped_over_the_rate() -> None:
    protocol = _accepted(dataclasses.replace(TIMING, max_frames_per_s=10.0))  # a burst of 1
    protocol.receive_frame(_heartbeat(0), 200 * MS)
    protocol.receive_frame(_heartbeat(0), 200 * MS)
    assert protocol.counters.frames_dropped == 1
    protocol.timeout(300 * MS)
    assert protocol.next_deadline() == 400 * MS  # not 350: heard at 200 ms


def test_the_clock_burst_keeps_the_best_sample_then_the_hello_is_due() -> None:
    protocol = WardenProtocol("robot", wire.PROTOCOL_RANGE, LinkCounters(), SYNCED)
    (ping,) = _messages(protocol.connect(0))
    assert ping == wire.ClockPing(seq=1, t0=0)
    (ping,) = _messages(protocol.receive_frame(_pong(ping, 5_000 + 1_000), 10_000))
    assert ping == wire.ClockPing(seq=2, t0=10_000)  # the next ping, at once
    (ping,) = _messages(protocol.receive_frame(_pong(ping, 11_000 + 2_000), 12_000))
    outputs = protocol.receive_frame(_pong(ping, 14_000 + 3_000), 16_000)
    # round trips 10 000, 2 000, 4 000: the second is the sync; offset = midpoint - t_server
    assert outputs == [Feed(ClockSyncEvent(t=16_000, domain=wire.SERVER_CLOCK_DOMAIN,
                                           offset=-2_000, round_trip=2_000)), HelloDue()]
    assert protocol.clock is not None and protocol.clock.offset == -2_000
    assert (protocol.counters.clock_round_trips, protocol.counters.clock_syncs) == (3, 1)


def test_an_unanswered_ping_ends_the_link_at_its_timeout() -> None:
    protocol = WardenProtocol("robot", wire.PROTOCOL_RANGE, LinkCounters(), SYNCED)
    protocol.connect(0)
    protocol.receive_frame(_heartbeat(0), 900 * MS)  # alive, but not answering the ping
    protocol.timeout(900 * MS)
    assert protocol.next_deadline() == 1000 * MS
    assert protocol.timeout(1000 * MS) == [Ended(ByeReason.CLOCK_TIMEOUT, "clock ping unanswered")]


def test_a_pong_that_does_not_echo_its_ping_is_a_violation() -> None:
    protocol = WardenProtocol("robot", wire.PROTOCOL_RANGE, LinkCounters(), SYNCED)
    protocol.connect(0)
    bad = wire.encode(wire.ClockPong(seq=1, t0=7, t_server=0))
    (ended,) = protocol.receive_frame(bad, 10)
    assert isinstance(ended, Ended) and ended.bye is ByeReason.PROTOCOL_VIOLATION
    assert protocol.counters.protocol_violations == 1


def test_no_offer_in_time_ends_the_handshake() -> None:
    protocol = WardenProtocol("robot", wire.PROTOCOL_RANGE, LinkCounters(), TIMING)
    protocol.connect(0)
    protocol.hello(HELLO, 0)
    t = 0
    while (deadline := protocol.next_deadline()) is not None and deadline < 5000 * MS:
        t = deadline
        protocol.receive_frame(_heartbeat(0), t)  # a peer alive but never offering
        protocol.timeout(t)
    assert protocol.next_deadline() == 5000 * MS
    assert protocol.timeout(5000 * MS) == [Ended(ByeReason.HANDSHAKE_TIMEOUT, "no offer in time")]


def test_the_clock_is_refreshed_in_the_session_and_reported_to_a_protocol_2_server() -> None:
    protocol = WardenProtocol("robot", wire.PROTOCOL_RANGE, LinkCounters(), SYNCED)
    ping = _messages(protocol.connect(0))[0]
    for t in (1_000, 2_000, 3_000):
        outputs = protocol.receive_frame(_pong(ping, t), t)
        ping = (_messages(outputs) or [ping])[0]
    protocol.hello(HELLO, 3_000)
    protocol.receive_frame(OFFER_FRAME, 4_000)
    report = wire.ClockReport(offset=protocol.clock.offset, round_trip=1_000)  # type: ignore[union-attr]
    assert _messages(protocol.on_decision(ACCEPT, 1, 5_000))[1] == report
    refresh_at = 5_000 + SYNCED.clock_refresh_ns
    protocol.receive_frame(_heartbeat(0), refresh_at)
    sent = _messages(protocol.timeout(refresh_at))
    assert sent[-1] == wire.ClockPing(seq=4, t0=refresh_at)


def test_requests_wait_for_room_in_the_window_and_coalesce() -> None:
    protocol = _accepted(dataclasses.replace(  # heartbeats out of the way of the window's
        TIMING, max_requests_in_flight=2, heartbeat_interval_ns=1000 * MS,
        heartbeat_timeout_ns=2000 * MS))
    for t in (10, 20):
        assert protocol.request(t) == [ObservationDue()]
        protocol.observe(SAMPLE, t, 4)
    assert protocol.request(30) == protocol.request(40) == []  # held, and coalesced
    assert protocol.counters.requests_waited == 1 and protocol.requests_in_flight == 2
    assert protocol.next_deadline() == 10 + 250 * MS  # the oldest request's expiry
    assert protocol.timeout(10 + 250 * MS) == [ObservationDue()]
    assert protocol.counters.requests_expired == 1


def test_a_chunk_answering_a_request_frees_its_slot() -> None:
    protocol = _accepted(dataclasses.replace(TIMING, max_requests_in_flight=1))
    protocol.request(10)
    protocol.observe(SAMPLE, 10, 4)
    assert protocol.request(20) == []
    answer = _chunk_frame({"chunk_id": "c", "observation_id": "robot/1"})
    assert protocol.receive_frame(answer, 30) == [ChunksWaiting()]
    fed, due = protocol.next_chunk(40)
    assert isinstance(fed, Feed) and due == ObservationDue()
    assert protocol.requests_in_flight == 0


def test_chunks_over_the_rate_are_refused_but_the_expected_answer_passes() -> None:
    protocol = _accepted(dataclasses.replace(TIMING, max_chunks_per_s=10.0))  # a burst of 1
    protocol.request(10)
    protocol.observe(SAMPLE, 10, 4)
    others = [_chunk_frame({"chunk_id": f"x{i}"}) for i in range(3)]
    assert protocol.receive_frame(others[0], 20) == [ChunksWaiting()]
    assert protocol.receive_frame(others[1], 20) == []  # over the chunk rate: dropped
    answer = _chunk_frame({"chunk_id": "c", "observation_id": "robot/1"})
    assert protocol.receive_frame(answer, 20) == [ChunksWaiting()]
    assert protocol.counters.chunks_dropped == 1 and protocol.chunks_waiting == 2
    fed = protocol.next_chunk(30)[0]
    assert isinstance(fed, Feed) and fed.event.frame == msgspec.msgpack.encode(  # type: ignore[union-attr]
        {"chunk_id": "c", "observation_id": "robot/1"})  # the answer goes first
    assert protocol.receive_frame(others[2], 100 * MS + 20) == [ChunksWaiting()]  # refilled


class LinkMachine(RuleBasedStateMachine):
    """Random frames, requests and instants into one protocol object, against a model of what
    may come out: heartbeats on schedule, at most the window in flight, the silence bound, one
    end per connection and nothing after it, deadlines that move past every instant handled."""

    def __init__(self) -> None:
        super().__init__()
        self.timing = dataclasses.replace(SYNCED, max_requests_in_flight=2,
                                          max_chunks_per_s=20.0, clock_burst=2)
        self.protocol = WardenProtocol("robot", wire.PROTOCOL_RANGE, LinkCounters(),
                                       self.timing)
        self.now = 0
        self.ends = 0

    @initialize()
    def open(self) -> None:
        self._connect()

    def _connect(self) -> None:
        self.ends, self.connected_at, self.last_rx = 0, self.now, self.now
        self.heartbeats = 0
        self.ping: wire.Message | None = None
        self._apply(self.protocol.connect(self.now))

    def _apply(self, outputs: list[Output]) -> None:
        for output in outputs:
            assert self.ends == 0, "nothing after the end of a connection"
            if isinstance(output, Ended):
                self.ends += 1
                if output.bye is ByeReason.HEARTBEAT_TIMEOUT:
                    assert self.now - self.last_rx >= self.timing.heartbeat_timeout_ns
            elif isinstance(output, HelloDue):
                self._apply(self.protocol.hello(HELLO, self.now))
            elif isinstance(output, OfferArrived):
                self._apply(self.protocol.on_decision(ACCEPT, 1, self.now))
            elif isinstance(output, ObservationDue):
                assert self.protocol.requests_in_flight < self.timing.max_requests_in_flight
                self._apply(self.protocol.observe(SAMPLE, self.now, 1))
            elif isinstance(output, Send):
                (message,) = _messages([output])
                self.heartbeats += isinstance(message, wire.Heartbeat)
                if isinstance(message, wire.ClockPing):
                    self.ping = message

    def _receive(self, data: bytes) -> None:
        if self.ends == 0:
            self.last_rx = self.now
        self._apply(self.protocol.receive_frame(data, self.now))

    @rule(step_ms=st.integers(0, 400))
    def time_passes(self, step_ms: int) -> None:
        deadline = self.protocol.next_deadline()
        self.now += step_ms * MS
        if self.ends == 0 and self.now - self.last_rx >= self.timing.heartbeat_timeout_ns:
            assert deadline is not None and deadline <= self.now
        if deadline is not None and deadline <= self.now:
            self._apply(self.protocol.timeout(self.now))
            after = self.protocol.next_deadline()
            assert after is None or after > self.now, "a deadline handled must move on"
        if self.ends == 0:  # one heartbeat per interval since the connection opened
            elapsed = self.now - self.connected_at
            assert self.heartbeats == elapsed // self.timing.heartbeat_interval_ns

    @rule(delay_us=st.integers(0, 2000), t_server=st.integers(-10**9, 10**9))
    def pong(self, delay_us: int, t_server: int) -> None:
        if self.ping is not None:
            self.now += delay_us * 1000
            self.time_passes(0)
            self._receive(_pong(self.ping, self.now + t_server))

    @rule()
    def offer(self) -> None:
        self._receive(OFFER_FRAME)

    @rule()
    def heartbeat(self) -> None:
        self._receive(_heartbeat(0))

    @rule(cited=st.integers(0, 6), chunk_id=st.text(max_size=3))
    def chunk(self, cited: int, chunk_id: str) -> None:
        if self.protocol.accepted:
            body = {"chunk_id": chunk_id, "observation_id": f"robot/{cited}"}
            self._receive(_chunk_frame(body))

    @rule(data=st.binary(max_size=40))
    def garbage(self, data: bytes) -> None:
        self._receive(data)

    @rule()
    def request(self) -> None:
        self._apply(self.protocol.request(self.now))

    @rule()
    def admission_slot(self) -> None:
        waiting = self.protocol.chunks_waiting
        outputs = self.protocol.next_chunk(self.now)
        assert bool(outputs) == bool(waiting)
        self._apply(outputs)

    @precondition(lambda self: self.ends == 1)
    @rule()
    def reconnect(self) -> None:
        self._connect()

    @invariant()
    def bounded(self) -> None:
        assert self.protocol.requests_in_flight <= self.timing.max_requests_in_flight
        assert self.ends <= 1
        if self.ends:
            assert self.protocol.next_deadline() is None and self.protocol.chunks_waiting == 0


LinkMachine.TestCase.settings = settings(max_examples=150, stateful_step_count=40,
                                         deadline=None)
test_the_link_protocol_under_random_frames_and_times = LinkMachine.TestCase
