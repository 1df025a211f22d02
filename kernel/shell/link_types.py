"""The policy link's public types: what the shell gives the client and what it reads back."""

from __future__ import annotations

import uuid
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from typing import Any, Protocol

import numpy as np

from assurance.handshake import ClientHello
from kernel import wire
from kernel.core import events as ev
from kernel.core.effects import Step

LINK_FRAME_BYTES = 1 << 16
"""Default frame limit: a 64 KiB frame holds a 1000 x 8 float64 chunk, twenty times any
policy's; a larger frame closes the connection before its payload is read."""


@dataclass(frozen=True, slots=True)
class RobotSample:
    """What the robot measures when an observation is captured (no goal, no hint)."""

    q: np.ndarray
    task_phase: str
    qd: np.ndarray | None = None
    wrench: np.ndarray | None = None
    gripper: float | None = None


class Gateway(Protocol):
    """The shell object that owns the core and the robot state.

    ``now_ns``: the client's monotonic clock, the core's time base. ``feed``: apply one event
    to the core, return what it produced. ``on``: have the core's effects and decision records
    (:class:`~kernel.core.effects.ChunkDecision`) of a type handed to a
    handler. ``client_side_hello``: this client's handshake side with the core's current queue
    epoch. ``capture_observation``: the robot, measured now.
    """

    def now_ns(self) -> int: ...

    def feed(self, event: ev.Event) -> Step: ...

    def on(self, kind: type, handler: Callable[[Any], None]) -> None: ...

    def client_side_hello(self) -> ClientHello: ...

    def capture_observation(self) -> RobotSample: ...


class LaunchedServer(Protocol):
    """A policy server this run started itself (the reference server in simulation): the
    client restarts it when it falls silent or stops accepting connections."""

    async def restart(self) -> str:
        """Stop the server, start it again; return its websocket URL."""
        ...


@dataclass(frozen=True, slots=True)
class ClientConfig:
    url: str
    client_id: str = field(default_factory=lambda: f"warden-{uuid.uuid4().hex[:8]}")
    protocol: tuple[int, int] = wire.PROTOCOL_RANGE
    max_frame_bytes: int = LINK_FRAME_BYTES
    max_frames_per_s: float = 1000.0
    """Frames beyond this rate are dropped undecoded (counted)."""
    max_chunks_per_s: float = 100.0
    """Chunks beyond this rate are dropped before decoding (counted); the first answer to an
    observation in flight is exempt (kernel/shell/link_budget.py)."""
    max_requests_in_flight: int = 4
    """Observations sent and not answered yet; a request waits while this many are out."""
    request_timeout_s: float = 0.25
    """An observation unanswered this long no longer counts as in flight (an answer to it
    would be stale by then in any phase of the shipped manifests)."""
    heartbeat_interval_s: float = 0.1
    heartbeat_timeout_s: float = 0.35
    """Below the phases' underrun escalation (the manifest checks it), so a dead link is
    DEGRADED (a new handshake recovers it) before a starved queue escalates to SAFE_HOLD (an
    operator must)."""
    handshake_timeout_s: float = 5.0
    open_timeout_s: float = 5.0
    close_timeout_s: float = 1.0
    """Bound on saying goodbye and closing, after the core has been told the link is down."""
    clock_burst: int = 8
    clock_refresh_s: float = 10.0
    clock_ping_timeout_s: float = 1.0
    backoff_initial_s: float = 0.05
    backoff_max_s: float = 2.0

    def __post_init__(self) -> None:
        if self.clock_burst < 1:
            raise ValueError("clock_burst must be at least 1")
        if not 0 < self.heartbeat_interval_s < self.heartbeat_timeout_s:
            raise ValueError("need 0 < heartbeat_interval_s < heartbeat_timeout_s")
        if not 0 < self.backoff_initial_s <= self.backoff_max_s:
            raise ValueError("need 0 < backoff_initial_s <= backoff_max_s")
        if not 0 < self.max_frame_bytes <= wire.MAX_FRAME_BYTES:
            raise ValueError(f"max_frame_bytes must be in 1..{wire.MAX_FRAME_BYTES}")
        if not (self.max_frames_per_s > 0 and self.max_chunks_per_s > 0):
            raise ValueError("frame and chunk rate limits must be positive")
        if self.max_requests_in_flight < 1 or not self.request_timeout_s > 0:
            raise ValueError("need max_requests_in_flight >= 1 and request_timeout_s > 0")


@dataclass(slots=True)
class LinkCounters:
    connects: int = 0
    connect_failures: int = 0
    reconnects: int = 0
    frames_in: int = 0
    frames_out: int = 0
    bytes_in: int = 0
    bytes_out: int = 0
    handshakes_accepted: int = 0
    handshakes_rejected: int = 0
    frames_dropped: int = 0
    """Over the frame rate: dropped undecoded."""
    chunks_in: int = 0
    chunks_dropped: int = 0
    """Over the chunk rate, or the chunk queue full: dropped, never fed to the core."""
    chunks_admitted: int = 0
    chunks_refused: int = 0
    malformed: int = 0
    observations_sent: int = 0
    requests_waited: int = 0
    """Requests held back because the window of observations in flight was full."""
    requests_expired: int = 0
    admissions_deferred: int = 0
    """Chunks whose admission waited for a later control period."""
    clock_round_trips: int = 0
    clock_syncs: int = 0
    heartbeat_misses: int = 0
    link_timeouts: int = 0
    protocol_violations: int = 0
    oversized: int = 0
    byes_sent: int = 0
    byes_received: int = 0
    server_restarts: int = 0
    server_restart_failures: int = 0

    def snapshot(self) -> dict[str, int]:
        return asdict(self)


class LinkState(StrEnum):
    IDLE = "idle"
    CONNECTING = "connecting"
    HANDSHAKING = "handshaking"
    ACCEPTED = "accepted"
    CLOSING = "closing"
    BACKOFF = "backoff"
    STOPPED = "stopped"
