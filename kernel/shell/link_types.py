"""The policy link's public types: what the shell gives the client and what it reads back."""

from __future__ import annotations

import uuid
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from typing import Any, Protocol

import numpy as np

from assurance.clock import ms_to_ns
from assurance.handshake import ClientHello
from assurance.rtc import Committed
from drivers.camera import CameraFrame
from kernel import wire
from kernel.core import events as ev
from kernel.core.effects import Step
from kernel.shell.link_credentials import LinkSecurity
from kernel.shell.link_settings import PolicySettings


@dataclass(frozen=True, slots=True, eq=False)
class SeenImage:
    """A camera's newest frame, ready to travel: ``data`` is its pixels as the manifest asks
    them sent (raw RGB bytes, or a JPEG file)."""

    frame: CameraFrame
    encoding: wire.ImageEncoding
    data: bytes

    def payload(self) -> wire.WireImage:
        f = self.frame
        return wire.image_payload(f.camera, self.encoding, f.image, self.data, f.t_capture_ns,
                                  f.digest, f.calibration_epoch)

    def stamp(self) -> ev.FrameStamp:
        f = self.frame
        return ev.FrameStamp(camera=f.camera, t_capture=f.t_capture_ns, digest=f.digest,
                             calibration_epoch=f.calibration_epoch)


@dataclass(frozen=True, slots=True)
class RobotSample:
    """What the robot measures when an observation is captured (no goal, no hint)."""

    q: np.ndarray
    task_phase: str
    qd: np.ndarray | None = None
    wrench: np.ndarray | None = None
    gripper: float | None = None
    committed: Committed | None = None
    """Real-time chunking: the committed actions from the one in force now on, one per step of
    the grid the link asked for (None: not asked for)."""
    images: tuple[SeenImage, ...] = ()
    """Each camera's newest frame (the manifest's ``[[cameras]]``; none without cameras)."""
    measured_ns: int | None = None
    """When ``q`` and the rest were measured, on the run's clock (None: not known; taken as
    the observation's sending)."""

    def taken_at(self, sent_ns: int) -> int:
        """When the observation was taken: its oldest frame's capture, or ``sent_ns``
        without frames (never later than ``sent_ns``)."""
        return min([sent_ns, *(image.frame.t_capture_ns for image in self.images)])

    def measured_at(self, sent_ns: int) -> int:
        """When the joints it carries were measured: the tick's sample with frames (the
        policy extrapolates from here), ``sent_ns`` without (as an observation always was)."""
        if not self.images:
            return sent_ns
        return min(sent_ns, self.measured_ns or sent_ns)


class CameraFrames(Protocol):
    """Where the link takes an observation's frames (kernel/shell/cameras.py)."""

    def images(self, now_ns: int) -> tuple[SeenImage, ...] | None:
        """Every camera's newest frame, encoded; None when one has none fresh enough."""
        ...

    async def fresh(self, since_ns: int, now_ns: Callable[[], int]) -> None:
        """Wait (bounded) for the cameras that take pictures on request to take one."""
        ...


class Gateway(Protocol):
    """The shell object that owns the core and the robot state.

    ``now_ns``: the client's monotonic clock, the core's time base. ``feed``: apply one event
    to the core, return what it produced. ``on``: have the core's effects and decision records
    (:class:`~kernel.core.effects.ChunkDecision`) of a type handed to a
    handler. ``client_side_hello``: this client's handshake side with the core's current queue
    epoch. ``capture_observation``: the robot, measured now (with ``prefix_grid_ns``, and
    the committed actions on that grid).
    """

    def now_ns(self) -> int: ...

    def feed(self, event: ev.Event) -> Step: ...

    def on(self, kind: type, handler: Callable[[Any], None]) -> None: ...

    def client_side_hello(self) -> ClientHello: ...

    def capture_observation(self, prefix_grid_ns: int | None = None,
                            at_ns: int | None = None) -> RobotSample: ...


class LaunchedServer(Protocol):
    """A policy server this run started itself (the reference server in simulation): the
    client restarts it when it falls silent or stops accepting connections."""

    async def restart(self) -> str:
        """Stop the server, start it again; return its websocket URL."""
        ...


@dataclass(frozen=True, slots=True)
class LinkTiming:
    """Every time and rate the protocol object decides on, in the unit it counts in (ns).

    ``clock_burst`` 0: the peer reads the robot's own clock (the in-process policy of a
    lockstep run), so there is no clock exchange.
    """

    heartbeat_interval_ns: int
    heartbeat_timeout_ns: int
    handshake_timeout_ns: int
    clock_burst: int
    clock_ping_timeout_ns: int
    clock_refresh_ns: int
    max_requests_in_flight: int
    request_timeout_ns: int
    max_frames_per_s: float
    max_chunks_per_s: float

    def __post_init__(self) -> None:
        if self.clock_burst < 0:
            raise ValueError("clock_burst must be at least 0")
        if not 0 < self.heartbeat_interval_ns < self.heartbeat_timeout_ns:
            raise ValueError("need 0 < heartbeat_interval_ns < heartbeat_timeout_ns")

    @classmethod
    def of(cls, policy: PolicySettings, *, handshake_timeout_s: float, clock_burst: int,
           clock_ping_timeout_s: float, clock_refresh_s: float) -> LinkTiming:
        return cls(
            heartbeat_interval_ns=ms_to_ns(policy.heartbeat_interval_ms),
            heartbeat_timeout_ns=ms_to_ns(policy.heartbeat_timeout_ms),
            handshake_timeout_ns=_ns(handshake_timeout_s), clock_burst=clock_burst,
            clock_ping_timeout_ns=_ns(clock_ping_timeout_s),
            clock_refresh_ns=_ns(clock_refresh_s),
            max_requests_in_flight=policy.max_requests_in_flight,
            request_timeout_ns=ms_to_ns(policy.request_timeout_ms),
            max_frames_per_s=policy.max_frames_per_s, max_chunks_per_s=policy.max_chunks_per_s)


def _ns(seconds: float) -> int:
    """The client's own knobs are in seconds; ``[policy]``'s in ms (``ms_to_ns``)."""
    return round(seconds * 1e9)


@dataclass(frozen=True, slots=True)
class ClientConfig:
    url: str
    client_id: str = field(default_factory=lambda: f"warden-{uuid.uuid4().hex[:8]}")
    wire_versions: tuple[int, int] = wire.PROTOCOL_RANGE
    """The range of warden's wire protocol versions the hello offers."""
    policy: PolicySettings = field(default_factory=PolicySettings)
    """The manifest's ``[policy]`` as read: what one policy peer may cost (frame and chunk
    rates, requests in flight, timeouts, heartbeats), bounded where it is declared."""
    security: LinkSecurity = field(default_factory=LinkSecurity)
    """``[policy.tls]`` and ``[policy.auth]`` as loaded (kernel/shell/link_security.py)."""
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
        if not 0 < self.backoff_initial_s <= self.backoff_max_s:
            raise ValueError("need 0 < backoff_initial_s <= backoff_max_s")

    @property
    def timing(self) -> LinkTiming:
        """What the protocol object times, from ``[policy]`` and the client's own knobs."""
        return LinkTiming.of(self.policy, handshake_timeout_s=self.handshake_timeout_s,
                             clock_burst=self.clock_burst,
                             clock_ping_timeout_s=self.clock_ping_timeout_s,
                             clock_refresh_s=self.clock_refresh_s)


@dataclass(slots=True)
class LinkCounters:
    connects: int = 0
    connect_failures: int = 0
    connects_refused: int = 0
    """Connection attempts that retrying will not mend: a certificate, a credential, a
    plain-text link to a TLS server, a server that is not warden's (counted in
    ``connect_failures`` too)."""
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

    def chunk_decided(self, admitted: bool) -> None:
        """The core admitted, or refused, a chunk this link carried."""
        self.chunks_admitted += admitted
        self.chunks_refused += not admitted

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
