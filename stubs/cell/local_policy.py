"""The reference policy, in process, on the virtual clock (lockstep runs and tests).

It plays the part of the policy server without a network: a request from the core becomes an
observation captured now, and the chunk comes back after a latency drawn from the same model
the server uses, as the same bytes the server would send (:func:`stubs.policy_server.chunk_frame`),
decoded by warden's own wire decoder. Times are in the client's own clock domain. Everything is
seeded, so a lockstep run is deterministic.
"""

from __future__ import annotations

import heapq
import itertools
from dataclasses import dataclass, field

import msgspec
import numpy as np

from assurance.envelope import decode_wire_chunk
from assurance.handshake import HandshakeOffer
from kernel.core.effects import RequestObservation
from kernel.core.events import ChunkEvent, HandshakeEvent, ObservationEvent
from kernel.shell.gateway import CoreGateway
from stubs.policy_server.cartesian import output_for
from stubs.policy_server.envelope import (
    ChunkSource,
    Proposal,
    ReplacementPolicy,
    chunk_envelope,
    encode_chunk_body,
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
    body: bytes = field(compare=False)


class LocalPolicyLink:
    """Connect (handshake) once, then answer every inference request of the core."""

    def __init__(self, config: LocalPolicyConfig, gateway: CoreGateway) -> None:
        self.config = config
        self.gateway = gateway
        self.rng = np.random.default_rng(config.seed)
        self._pending: list[_Pending] = []
        self._order = itertools.count()
        self._sequence = itertools.count(1)
        self._observations = itertools.count(1)
        self._output = output_for(config.offer.action_frame, config.offer.action_units)
        self._source = _source(config)
        self.requests = 0
        gateway.on(RequestObservation, self._on_request)

    def connect(self) -> None:
        epoch = self.gateway.core.state.epoch
        offer = msgspec.structs.replace(self.config.offer, queue_epoch=epoch)
        self.gateway.feed(HandshakeEvent(t=self.gateway.now_ns(), offer=offer))

    def deliver_due(self) -> None:
        """Hand the core every chunk whose simulated inference has finished by now."""
        now = self.gateway.now_ns()
        while self._pending and self._pending[0].due_ns <= now:
            pending = heapq.heappop(self._pending)
            chunk = decode_wire_chunk(pending.body, now)
            self.gateway.feed(ChunkEvent(now, chunk, pending.body))

    def _on_request(self, _: RequestObservation) -> None:
        self.requests += 1
        t = self.gateway.now_ns()
        robot = self.gateway.capture_observation()
        observation_id = f"local/{next(self._observations)}"
        self.gateway.feed(ObservationEvent(t=t, observation_id=observation_id))
        latency_ns = round(self.config.latency.sample_s(self.rng) * 1e9)
        body = encode_chunk_body(chunk_envelope(
            self._source, self._proposal(observation_id, robot, t, latency_ns)))
        heapq.heappush(self._pending, _Pending(t + latency_ns, next(self._order), body))

    def _proposal(self, observation_id: str, robot: object, t_obs: int,
                  latency_ns: int) -> Proposal:
        q = np.asarray(robot.q, dtype=float)  # type: ignore[attr-defined]
        lead_ns = latency_ns + 3_000_000
        qd = robot.qd  # type: ignore[attr-defined]
        actions = self.config.policy.actions(q, lead_ns * 1e-9, self.rng, qd)
        if self._output is not None:
            actions = self._output(q, actions)
        epoch = self.gateway.core.state.epoch
        sequence = next(self._sequence)
        return Proposal(
            chunk_id=f"local-e{epoch}-s{sequence}", sequence=sequence, queue_epoch=epoch,
            task_phase=str(robot.task_phase),  # type: ignore[attr-defined]
            observation_id=observation_id, observed_q=q, actions=actions,
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
