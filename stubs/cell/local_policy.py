"""The reference policy, in process, on the virtual clock (lockstep runs and tests).

It plays the part of the policy server without a network, over an in-memory pipe to the same
sans-I/O protocol object the live client drives (:class:`kernel.shell.link_protocol.
WardenProtocol`): its offer goes in as an ``offer`` frame, the core's decision comes back as
the frame the protocol sends; a request from the core becomes the protocol's observation frame,
which this policy reads, and the chunk comes back after a latency drawn from the same model the
server uses, as the same bytes the server would send (:func:`stubs.policy_server.chunk_frame`).
The protocol's timing runs on the virtual clock too: the run wakes it when a tick passes its
deadline, and this policy answers each heartbeat. Times are in the client's own clock domain
(no clock exchange: ``clock_burst`` 0). Everything is seeded, so a lockstep run is
deterministic.
"""

from __future__ import annotations

import heapq
import itertools
from dataclasses import dataclass, field

import msgspec
import numpy as np

from assurance.handshake import HandshakeOffer
from kernel import wire
from kernel.core.effects import ChunkDecision, RequestObservation
from kernel.shell.gateway import CoreGateway
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
from kernel.shell.link_settings import PolicySettings
from kernel.shell.link_types import LinkCounters, LinkTiming
from peer.envelope import (
    ChunkSource,
    Proposal,
    ReplacementPolicy,
    chunk_frame,
)
from stubs.policy_server.cartesian import output_for
from stubs.policy_server.policy import InsertionPolicy, LatencyModel


def local_timing(policy: PolicySettings) -> LinkTiming:
    """The protocol's timing for an in-process policy on the virtual clock."""
    return LinkTiming.of(policy, handshake_timeout_s=5.0, clock_burst=0,
                         clock_ping_timeout_s=1.0, clock_refresh_s=10.0)


@dataclass(frozen=True, slots=True)
class LocalPolicyConfig:
    offer: HandshakeOffer
    policy: InsertionPolicy
    latency: LatencyModel
    max_observation_age_ms: float = 80.0
    max_action_age_ms: float = 250.0
    seed: int = 0
    timing: LinkTiming = field(default_factory=lambda: local_timing(PolicySettings()))
    """The link's timers and budget (the manifest's ``[policy]``); no clock exchange: this
    policy reads the robot's own clock."""


@dataclass(order=True)
class _Pending:
    due_ns: int
    order: int
    frame: bytes = field(compare=False)


class LocalPolicyLink:
    """Connect (handshake) once, then answer every inference request of the core."""

    def __init__(self, config: LocalPolicyConfig, gateway: CoreGateway) -> None:
        self.config = config
        self.gateway = gateway
        self.counters = LinkCounters()
        self.protocol = WardenProtocol("local", wire.PROTOCOL_RANGE, self.counters,
                                       config.timing)
        self.ended: str | None = None
        """Why the protocol ended the session (a refused handshake), if it did."""
        self.rng = np.random.default_rng(config.seed)
        self._pending: list[_Pending] = []
        self._order = itertools.count()
        self._sequence = itertools.count(1)
        self._output = output_for(config.offer.action_frame, config.offer.action_units)
        self._source = _source(config)
        self.requests = 0
        gateway.on(RequestObservation, self._on_request)
        gateway.on(ChunkDecision, self._on_decision)

    def connect(self) -> None:
        """Open the session: the protocol's hello, this policy's offer, the core's decision."""
        gateway = self.gateway
        self._carry(self.protocol.connect(gateway.now_ns()))
        epoch = gateway.client_side_hello().queue_epoch
        offer = msgspec.structs.replace(self.config.offer, queue_epoch=epoch)
        self._receive(wire.encode(wire.Offer(server_id="local", offer=offer)))

    def deliver_due(self) -> None:
        """Wake the protocol at its deadlines (heartbeats, expired requests), then hand the core
        every chunk whose simulated inference has finished by now."""
        now = self.gateway.now_ns()
        deadline = self.protocol.next_deadline()
        if deadline is not None and deadline <= now:
            self._carry(self.protocol.timeout(now))
        while self._pending and self._pending[0].due_ns <= now:
            pending = heapq.heappop(self._pending)
            if self.protocol.accepted:  # no session (refused): the policy's chunks reach no core
                self._receive(pending.frame)

    def _receive(self, frame: bytes) -> None:
        """A frame from this policy, over the pipe, read now."""
        self._carry(self.protocol.receive_frame(frame, self.gateway.now_ns()))

    def _on_decision(self, decided: ChunkDecision) -> None:
        self._carry(self.protocol.on_decision(
            decided, self.gateway.client_side_hello().queue_epoch, self.gateway.now_ns()))

    def _on_request(self, _: RequestObservation) -> None:
        self.requests += 1
        self._carry(self.protocol.request(self.gateway.now_ns()))

    def _carry(self, outputs: list[Output]) -> None:
        gateway, protocol = self.gateway, self.protocol
        for output in outputs:
            if isinstance(output, Send):
                self._policy_reads(output.data)
            elif isinstance(output, Feed):
                gateway.feed(output.event)
            elif isinstance(output, HelloDue):
                self._carry(protocol.hello(gateway.client_side_hello(), gateway.now_ns()))
            elif isinstance(output, OfferArrived):
                step = gateway.feed(protocol.handshake_event(output.offer, gateway.now_ns()))
                for record in step.decisions:
                    self._carry(protocol.on_decision(
                        record, gateway.client_side_hello().queue_epoch, gateway.now_ns()))
            elif isinstance(output, ChunksWaiting):  # admitted at once: no control period
                self._carry(protocol.next_chunk(gateway.now_ns()))
            elif isinstance(output, ObservationDue):
                now = gateway.now_ns()
                sample = gateway.capture_observation(output.prefix_grid_ns, now)
                self._carry(protocol.observe(sample, now, gateway.client_side_hello().queue_epoch))
            elif isinstance(output, Ended):  # a refused handshake: no session, no chunks
                self.ended = output.detail

    def _policy_reads(self, data: bytes) -> None:
        """This policy's side of the pipe: an observation is answered by a chunk after the
        modelled latency, a heartbeat by a heartbeat (so the link never falls silent)."""
        message = wire.decode_body(frame := wire.decode_frame(data), wire.message_type(frame))
        if isinstance(message, wire.Heartbeat):
            self._receive(wire.encode(wire.Heartbeat(seq=message.seq, t_send=message.t_send)))
        elif isinstance(message, wire.Observation):
            latency_ns = round(self.config.latency.sample_s(self.rng) * 1e9)
            frame_out = chunk_frame(self._source, self._proposal(message, latency_ns))
            heapq.heappush(self._pending, _Pending(message.t_event + latency_ns,
                                                   next(self._order), frame_out))

    def _proposal(self, observation: wire.Observation, latency_ns: int) -> Proposal:
        q = wire.payload_vector(observation.q)
        qd = None if observation.qd is None else wire.payload_vector(observation.qd)
        t_obs = observation.t_event
        lead_ns = latency_ns + 3_000_000
        actions = self.config.policy.actions(q, lead_ns * 1e-9, self.rng, qd)
        if self._output is not None:
            actions = self._output(q, actions)
        epoch = observation.queue_epoch
        sequence = next(self._sequence)
        return Proposal(
            chunk_id=f"local-e{epoch}-s{sequence}", sequence=sequence, queue_epoch=epoch,
            task_phase=observation.task_phase,
            observation_id=observation.observation_id, observed_q=q, actions=actions,
            first_action_time=t_obs + lead_ns, observation_event_time=t_obs,
            observation_arrival_time=t_obs, inference_start=t_obs,
            inference_end=t_obs + latency_ns, server_send=t_obs + latency_ns,
        )


def _source(config: LocalPolicyConfig) -> ChunkSource:
    offer = config.offer
    return ChunkSource(
        policy_checkpoint=offer.policy_checkpoint, config_hash=offer.config_hash,
        skill=offer.skill, skill_version=offer.skill_version or "",
        controller_mode=offer.controller_mode or "",
        calibration_epoch=offer.calibration_epoch or "",
        action_units=offer.action_units, action_frame=offer.action_frame,
        action_dt_ns=round(config.policy.action_dt_s * 1e9),
        max_observation_age_ns=round(config.max_observation_age_ms * 1e6),
        max_action_age_ns=round(config.max_action_age_ms * 1e6),
        replacement_policy=ReplacementPolicy.BLEND, clock_domain="client", fallback_id=None,
    )
