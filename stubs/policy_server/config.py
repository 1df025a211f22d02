"""Configuration of the reference policy server.

The defaults make a server compatible with the standard cell of ``tools/scenarios/base.py``
(same checkpoint, config hash, observation keys, skill and calibration); change one field to
make it incompatible on purpose.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from peer.access import Access
from peer.envelope import ChunkSource, ReplacementPolicy
from peer.frames import CameraShape
from peer.handshake import HandshakeOffer
from peer.protocol import MAX_FRAME_BYTES, PROTOCOL_RANGE
from stubs.policy_server.faults import FaultConfig
from stubs.policy_server.policy import InsertionPolicy, LatencyModel

DEFAULT_START = (0.0, -1.2, 1.5, -1.87, -1.57, 0.0)
DEFAULT_GOAL = (0.1, -1.35, 1.7, -1.92, -1.57, 0.05)
"""Above the insertion hole, a few centimetres from the standard cell's start pose."""


@dataclass(frozen=True, slots=True)
class ServerConfig:
    host: str = "127.0.0.1"
    port: int = 0
    server_id: str = "policy-ref"
    # the handshake offer
    policy_checkpoint: str = "act-insert-2026-07"
    config_hash: str = "cfg-9f2c"
    observation_keys: tuple[str, ...] = ("wrist_rgb", "scene_rgb", "joint_pos", "wrench")
    action_dim: int = 6
    action_units: str = "rad"
    action_frame: str = "joint"
    skill: str = "peg_insert"
    skill_version: str = "3.1.0"
    controller_mode: str = "joint_position"
    calibration_epoch: str = "cal-12"
    protocol: tuple[int, int] = PROTOCOL_RANGE
    """Offered in the handshake; the core picks the highest common version."""
    wire_protocol: tuple[int, int] = PROTOCOL_RANGE
    """The versions this server can parse at all; no overlap with the Hello ends the talk."""
    # the policy
    horizon: int = 20
    action_dt_ms: float = 20.0
    goal: tuple[float, ...] = DEFAULT_GOAL
    max_speed: float = 0.25
    max_acceleration: float | None = None
    """rad/s²: None moves at full speed at once; set, the policy ramps up and brakes."""
    noise_std: float = 1e-4
    latency: LatencyModel = field(default_factory=LatencyModel)
    lead_ms: float | None = None
    """First action this long after the observation; default: latency p95 + 3 ms."""
    replacement_policy: ReplacementPolicy = ReplacementPolicy.REPLACE
    rtc: bool = False
    """Offer real-time chunking: a chunk answering an observation that carries the committed
    prefix starts where the prefix does, repeats its first ``delay`` actions and plans on from
    the last of them."""
    cameras: tuple[CameraShape, ...] = ()
    """The cameras every observation must carry a frame of (protocol 3)."""
    max_observation_age_ms: float = 80.0
    max_action_age_ms: float = 200.0
    seed: int = 0
    # the link
    clock_offset_ns: int = 0
    """Added to this machine's monotonic clock: the server's clock is deliberately foreign."""
    heartbeat_interval_s: float = 0.1
    heartbeat_timeout_s: float = 1.0
    faults: FaultConfig = field(default_factory=FaultConfig)
    access: Access = field(default_factory=Access)
    """TLS, client certificates and a bearer token (default: plain ``ws://``, anyone)."""

    def offer(self, queue_epoch: int) -> HandshakeOffer:
        return HandshakeOffer(
            policy_checkpoint=self.policy_checkpoint, config_hash=self.config_hash,
            observation_keys=self.observation_keys, action_dim=self.action_dim,
            action_units=self.action_units, action_frame=self.action_frame,
            chunk_horizon=self.horizon, protocol=self.protocol, skill=self.skill,
            skill_version=self.skill_version, controller_mode=self.controller_mode,
            calibration_epoch=self.calibration_epoch, queue_epoch=queue_epoch, rtc=self.rtc,
        )

    def chunk_source(self) -> ChunkSource:
        """What every chunk repeats; the ``checkpoint`` fault claims another checkpoint."""
        return ChunkSource(
            policy_checkpoint=self.faults.checkpoint or self.policy_checkpoint,
            config_hash=self.config_hash, skill=self.skill, skill_version=self.skill_version,
            controller_mode=self.controller_mode, calibration_epoch=self.calibration_epoch,
            action_units=self.action_units, action_frame=self.action_frame,
            action_dt_ns=round(self.action_dt_ms * 1e6),
            max_observation_age_ns=round(self.max_observation_age_ms * 1e6),
            max_action_age_ns=round(self.max_action_age_ms * 1e6),
            replacement_policy=self.replacement_policy,
        )

    def policy(self) -> InsertionPolicy:
        return InsertionPolicy(
            goal=np.asarray(self.goal, dtype=float), max_speed=self.max_speed,
            max_acceleration=self.max_acceleration,
            noise_std=self.noise_std, horizon=self.horizon, action_dt_s=self.action_dt_ms / 1e3,
        )

    @property
    def max_frame_bytes(self) -> int:
        """The largest frame taken: a chunk-sized frame, plus the cameras' raw pixels and
        their fields (the transport refuses more: close 1009)."""
        pixels = sum(camera.raw_bytes for camera in self.cameras)
        return MAX_FRAME_BYTES + (pixels + (1 << 16) if self.cameras else 0)

    @property
    def lead_ns(self) -> int:
        lead = self.lead_ms if self.lead_ms is not None else self.latency.p95_ms + 3.0
        return round(lead * 1e6)
