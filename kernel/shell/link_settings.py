"""``[policy]``: the policy server a run talks to and what one policy peer may cost.

One type, in the manifest's unit (milliseconds, as written), used by the link directly
(:class:`kernel.shell.link_types.ClientConfig` holds it); ``LinkTiming.of`` (link_types.py)
is the one conversion to the nanoseconds the link's protocol object times in (the ``*_s``
properties remain for readers counting in seconds). Each field's range is declared on the
field (:mod:`kernel.tables` checks it while the manifest loads; docs/manifest.md, "Bounds").
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated

import msgspec
from msgspec import Meta

from kernel.scenario.bounds import (
    CHUNK_HORIZON_MAX,
    CLOCK_OFFSET_MAX_MS,
    DURATION_MAX_MS,
    NOISE_MAX_RAD,
    PERIOD_MAX_MS,
    PERIOD_MIN_MS,
    PORT_MAX,
)
from kernel.wire import MAX_FRAME_BYTES

LinkTime = Annotated[float, Meta(ge=1.0, le=DURATION_MAX_MS)]
"""A link timeout or heartbeat, ms: beyond a minute a dead link goes unnoticed."""
Window = Annotated[int, Meta(ge=1, le=64)]
"""More than 64 requests in flight, or admissions per period, is more than a chunk queue
holds."""
LatencyMs = Annotated[float, Meta(ge=0.0, le=DURATION_MAX_MS)]


class PolicyProtocol(StrEnum):
    """What the policy server speaks."""

    WARDEN = "warden"
    """warden's own protocol (docs/protocol.md): the reference server, a server built on
    :mod:`stubs.policy_server`'s envelope."""
    OPENPI = "openpi"
    """An unmodified openpi websocket server (kernel/shell/link_openpi.py)."""


class OpenpiSettings(msgspec.Struct, frozen=True, kw_only=True):
    """``[policy.openpi]``: what the deployment declares about an openpi server, which states
    none of it itself."""

    policy_checkpoint: Annotated[str, Meta(min_length=1, max_length=128)]
    """The checkpoint the server runs, as declared (unattested: the ``[[allowlist]]`` entry
    pairs it with ``openpi-sha256:`` and the digest of the server's metadata frame)."""
    state_key: Annotated[str, Meta(min_length=1, max_length=128)] = "observation/state"
    """The observation key of the robot's state (the joints, then the gripper's opening)."""
    prompt_key: Annotated[str, Meta(min_length=1, max_length=128)] = "prompt"
    prompt: Annotated[str, Meta(max_length=1024)] | None = None
    """The task's instruction, sent with every observation (None: no prompt key)."""
    images: dict[Annotated[str, Meta(min_length=1, max_length=64)],
                 Annotated[str, Meta(min_length=1, max_length=128)]] = {}
    """Each ``[[cameras]]`` name → the observation key the server reads its frames under
    (``wrist_rgb = "observation/wrist_image"``), sent as ``uint8`` H×W×3 arrays."""


FilePath = Annotated[str, Meta(min_length=1, max_length=4096)]
"""A file the manifest names (relative: to the manifest's directory)."""


class TlsSettings(msgspec.Struct, frozen=True, kw_only=True):
    """``[policy.tls]``: speak ``wss://`` and trust only the server certificates that chain
    to ``ca_file`` (kernel/shell/link_security.py)."""

    ca_file: FilePath
    """PEM bundle of the authorities the server's certificate must chain to."""
    cert_file: FilePath | None = None
    """PEM certificate this robot presents (a server that asks for one); with ``key_file``."""
    key_file: FilePath | None = None
    server_name: Annotated[str, Meta(min_length=1, max_length=253)] | None = None
    """The name the server's certificate must carry (default: ``host``)."""


class AuthSettings(msgspec.Struct, frozen=True, kw_only=True):
    """``[policy.auth]``: where the link's bearer token is kept. Exactly one of the two: the
    token itself is never manifest data (a manifest is signed and journaled, not secret)."""

    token_file: FilePath | None = None
    """A file holding the token (one line; readable by its owner only)."""
    token_env: Annotated[str, Meta(pattern=r"^[A-Za-z_][A-Za-z0-9_]{0,127}$")] | None = None
    """An environment variable holding the token (a systemd ``LoadCredential``/``Environment``
    of the service)."""


class PolicySettings(msgspec.Struct, frozen=True, kw_only=True):
    protocol: PolicyProtocol = PolicyProtocol.WARDEN
    openpi: OpenpiSettings | None = None
    """``[policy.openpi]``: required with ``protocol = "openpi"``, refused without it."""
    tls: TlsSettings | None = None
    """``[policy.tls]``: ``wss://`` (None: plain ``ws://``)."""
    auth: AuthSettings | None = None
    """``[policy.auth]``: a bearer token sent when connecting (None: none)."""
    launch: bool = True
    host: str = "127.0.0.1"
    expose: bool = False
    """A launched reference server may listen on a ``host`` that is not loopback (reachable
    from other hosts: the server warden launches has neither TLS nor a token). Off: such a
    host is refused."""
    port: Annotated[int, Meta(ge=0, le=PORT_MAX)] = 0
    # The reference server's model (stubs/cell/reference.py)
    latency_median_ms: LatencyMs = 30.0
    latency_p95_ms: LatencyMs = 60.0
    chunk_horizon: Annotated[int, Meta(ge=1, le=CHUNK_HORIZON_MAX)] = 20
    action_dt_ms: Annotated[float, Meta(ge=PERIOD_MIN_MS, le=PERIOD_MAX_MS)] = 20.0
    noise_rad: Annotated[float, Meta(ge=0.0, le=NOISE_MAX_RAD)] = 0.0005
    rtc: bool = False
    """The reference server offers real-time chunking (assurance/rtc.py)."""
    clock_offset_ms: Annotated[float, Meta(ge=-CLOCK_OFFSET_MAX_MS, le=CLOCK_OFFSET_MAX_MS)] = 0.0
    # What one policy peer may cost (kernel/shell/link_budget.py). A frame rate above
    # 100 000/s or a chunk rate above 10 000/s is no limit at the GIL's pace.
    max_frame_bytes: Annotated[int, Meta(ge=1, le=MAX_FRAME_BYTES)] = 1 << 16
    """A 64 KiB frame holds a 1000 x 8 float64 chunk, twenty times any policy's; a larger
    frame closes the connection before its payload is read."""
    max_frames_per_s: Annotated[float, Meta(ge=1.0, le=100_000.0)] = 1000.0
    """Frames beyond this rate are dropped undecoded (counted)."""
    max_chunks_per_s: Annotated[float, Meta(ge=0.1, le=10_000.0)] = 100.0
    """Chunks beyond this rate are dropped before decoding (counted); the first answer to an
    observation in flight is exempt."""
    max_requests_in_flight: Window = 4
    """Observations sent and not answered yet; a request waits while this many are out."""
    request_timeout_ms: LinkTime = 250.0
    """An observation unanswered this long no longer counts as in flight (an answer to it
    would be stale by then in any phase of the shipped manifests)."""
    admissions_per_period: Window = 1
    heartbeat_interval_ms: LinkTime = 100.0
    heartbeat_timeout_ms: LinkTime = 350.0
    """Below the phases' underrun escalation (the manifest checks it), so a dead link is
    DEGRADED (a new handshake recovers it) before a starved queue escalates to SAFE_HOLD (an
    operator must)."""

    def __post_init__(self) -> None:
        if not self.heartbeat_timeout_ms > self.heartbeat_interval_ms:
            raise ValueError(f"heartbeat_timeout_ms ({self.heartbeat_timeout_ms!r}) must be "
                             f"longer than heartbeat_interval_ms ({self.heartbeat_interval_ms})")

    @property
    def link_loss_bound_ms(self) -> float:
        """How long a dead link may go unnoticed, with one heartbeat of margin."""
        return self.heartbeat_timeout_ms + self.heartbeat_interval_ms

    @property
    def request_timeout_s(self) -> float:
        return self.request_timeout_ms / 1000.0

    @property
    def heartbeat_interval_s(self) -> float:
        return self.heartbeat_interval_ms / 1000.0

    @property
    def heartbeat_timeout_s(self) -> float:
        return self.heartbeat_timeout_ms / 1000.0
