"""The reference policy, in process, on the virtual clock (lockstep runs and tests).

It plays the part of the policy server without a network, over an in-memory pipe to the same
sans-I/O protocol object the live client drives (:class:`kernel.shell.link_protocol.
WardenProtocol`): its offer goes in as an ``offer`` frame, the core's decision comes back as
the frame the protocol sends; a request from the core becomes the protocol's observation frame,
which this policy reads, and the chunk comes back after a latency drawn from the same model the
server uses, as the same bytes the server would send (:func:`stubs.policy_server.chunk_frame`).
Times are in the client's own clock domain. Everything is seeded, so a lockstep run is
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
    ChunkArrived,
    Ended,
    Feed,
    OfferArrived,
    Output,
    Send,
    WardenProtocol,
)
from kernel.shell.link_types import LinkCounters
from stubs.policy_server.cartesian import output_for
from stubs.policy_server.envelope import (
    ChunkSource,
    Proposal,
    ReplacementPolicy,
    chunk_frame,
)
from stubs.policy_server.policy import InsertionPolicy, LatencyModel


@dataclass(frozen=True, slots=True)
class LocalPolicyConfig:
    offer: HandshakeOffer
    policy: InsertionPolicy
    latency: LatencyModel
    max_observation_age_ms: float = 80.0
    max_action_age_ms: float = 250.0
    seed: int = 0


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
        self.protocol = WardenProtocol("local", wire.PROTOCOL_RANGE, self.counters)
        self.sent: list[bytes] = []
        self.ended: str | None = None
        """The frames the protocol sent this policy (the in-memory pipe's other direction)."""
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
        self.protocol.begin()
        self._carry(self.protocol.hello(gateway.client_side_hello()))
        epoch = gateway.client_side_hello().queue_epoch
        offer = msgspec.structs.replace(self.config.offer, queue_epoch=epoch)
        frame = wire.encode(wire.Offer(server_id="local", offer=offer))
        for output in self.protocol.receive_frame(frame, gateway.now_ns()):
            if isinstance(output, OfferArrived):
                step = gateway.feed(self.protocol.handshake_event(output.offer,
                                                                  gateway.now_ns()))
                for record in step.decisions:
                    self._carry(self.protocol.on_decision(
                        record, gateway.client_side_hello().queue_epoch))

    def deliver_due(self) -> None:
        """Hand the core every chunk whose simulated inference has finished by now."""
        now = self.gateway.now_ns()
        while self._pending and self._pending[0].due_ns <= now:
            pending = heapq.heappop(self._pending)
            if not self.protocol.accepted:
                continue  # no session (refused): the policy's chunks reach no core
            for output in self.protocol.receive_frame(pending.frame, now):
                if isinstance(output, ChunkArrived):
                    self.gateway.feed(self.protocol.chunk_event(output.frame, now))

    def _on_decision(self, decided: ChunkDecision) -> None:
        self.protocol.on_decision(decided, self.gateway.client_side_hello().queue_epoch)

    def _carry(self, outputs: list[Output]) -> None:
        for output in outputs:
            if isinstance(output, Send):
                self.sent.append(output.data)
            elif isinstance(output, Feed):
                self.gateway.feed(output.event)
            elif isinstance(output, Ended):  # a refused handshake: no session, no chunks
                self.ended = output.detail

    def _on_request(self, _: RequestObservation) -> None:
        self.requests += 1
        t = self.gateway.now_ns()
        self.sent.clear()
        self._carry(self.protocol.observe(self.gateway.capture_observation(), t,
                                          self.gateway.client_side_hello().queue_epoch))
        observation = self._read(self.sent[-1])
        latency_ns = round(self.config.latency.sample_s(self.rng) * 1e9)
        frame = chunk_frame(self._source, self._proposal(observation, latency_ns))
        heapq.heappush(self._pending, _Pending(t + latency_ns, next(self._order), frame))

    @staticmethod
    def _read(data: bytes) -> wire.Observation:
        message = wire.decode_body(frame := wire.decode_frame(data), wire.message_type(frame))
        if not isinstance(message, wire.Observation):
            raise RuntimeError(f"the local policy got {type(message).__name__}, not an "
                               "observation")
        return message

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
