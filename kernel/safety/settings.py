"""``[safety]``: the independent safety monitor's table in a deployment manifest.

warden reads only what its heartbeat sender needs (the socket and how often to send); the
monitor (``warden safety MANIFEST``) reads all of it. Every key has a documented default except
``max_wrist_force_n``, which the monitor requires wherever it reads the wrist sensor (a force
limit nobody chose is no limit): see docs/manifest.md, "[safety]".
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from msgspec import Meta

from drivers.settings import Settings
from kernel.scenario.bounds import FORCE_MAX_N

DEFAULT_DIRECTORY = "/run/warden-safety"
"""The monitor's runtime directory under systemd (``RuntimeDirectory=warden-safety``)."""
HEARTBEAT_NAME, STATUS_NAME = "heartbeat.sock", "status.sock"


Ms = Annotated[float, Meta(ge=10.0, le=10_000.0)]
"""A timeout or an interval of the monitor, ms."""


class SafetySettings(Settings, frozen=True, kw_only=True):
    heartbeat_socket: str = ""
    """The Unix datagram socket the monitor binds and warden's control loop sends to; empty:
    ``/run/warden-safety/heartbeat.sock``."""
    status_socket: str = ""
    """The Unix stream socket ``warden safety status`` asks; empty:
    ``/run/warden-safety/status.sock``."""
    group: str = ""
    """The group that may send heartbeats and ask for status (both sockets are 0660 to it);
    empty: the monitor's own group (``Group=warden`` in its unit)."""
    heartbeat_periods: Annotated[int, Meta(ge=1, le=1000)] = 5
    """warden sends one heartbeat every this many completed control ticks."""
    heartbeat_timeout_ms: Ms = 200.0
    """No heartbeat for this long (sender's clock, the same CLOCK_MONOTONIC) and the monitor
    stops the arm."""
    closing_timeout_ms: Annotated[float, Meta(ge=100.0, le=120_000.0)] = 10_000.0
    """After warden says its loop ended (CLOSING), how long it may take to hold the arm and
    close the device before it must say END; longer counts as a lost heartbeat."""
    check_period_ms: Annotated[float, Meta(ge=1.0, le=100.0)] = 4.0
    """How often the monitor reads the device and checks everything."""
    device_timeout_ms: Ms = 250.0
    """The device's data older than this (or unanswered) counts as the device lost."""
    position_margin_rad: Annotated[float, Meta(ge=0.0, le=0.5)] = 0.02
    """Allowance beyond each joint's position limit before a breach (measured overshoot)."""
    velocity_margin: Annotated[float, Meta(ge=0.0, le=1.0)] = 0.1
    """Allowance beyond each joint's velocity limit, as a fraction of it (0.1: 110 %)."""
    moving_rad_s: Annotated[float, Meta(ge=0.001, le=1.0)] = 0.05
    """A joint faster than this is moving: motion with no warden heartbeat is a breach, and a
    breach that persists while the arm moves is stopped again."""
    restop_interval_ms: Annotated[float, Meta(ge=10.0, le=60_000.0)] = 500.0
    """How soon a stop is repeated while a breach persists and the arm still moves."""
    max_wrist_force_n: Annotated[float, Meta(gt=0.0, le=FORCE_MAX_N)] | None = None
    """Largest force (norm of Fx, Fy, Fz at the wrist sensor, N) before the monitor stops the
    arm. Required by the monitor for a device whose wrist sensor it reads (ur_rtde, sim)."""
    sim_port: Annotated[int, Meta(ge=0, le=65535)] = 0
    """Simulation only (driver ``sim``): the loopback TCP port of the simulated world's
    test-only control port (its ground truth and a brake); 0: not served."""

    def __post_init__(self) -> None:
        super().__post_init__()
        problems = _problems(self)
        if problems:
            raise ValueError("; ".join(problems))

    @property
    def heartbeat_path(self) -> Path:
        return Path(self.heartbeat_socket or f"{DEFAULT_DIRECTORY}/{HEARTBEAT_NAME}")

    @property
    def status_path(self) -> Path:
        return Path(self.status_socket or f"{DEFAULT_DIRECTORY}/{STATUS_NAME}")

    @property
    def heartbeat_timeout_ns(self) -> int:
        return round(self.heartbeat_timeout_ms * 1e6)

    @property
    def closing_timeout_ns(self) -> int:
        return round(self.closing_timeout_ms * 1e6)


def _problems(s: SafetySettings) -> list[str]:
    """The rules across fields (each field's own range is on the field)."""
    problems = []
    if s.heartbeat_timeout_ms < 2 * s.check_period_ms:
        problems.append(f"heartbeat_timeout_ms = {s.heartbeat_timeout_ms} must be at least two "
                        f"check periods ({2 * s.check_period_ms} ms)")
    for key, path in (("heartbeat_socket", s.heartbeat_socket),
                      ("status_socket", s.status_socket)):
        if path and not path.startswith("/"):
            problems.append(f"{key} = {path!r} must be an absolute path")
    return problems


def check_against_period(settings: SafetySettings, control_period_ns: int) -> str | None:
    """A timeout that the heartbeat's own spacing would already exceed is no timeout: it
    must leave room for at least two heartbeats. Returns the problem, or None."""
    spacing_ms = settings.heartbeat_periods * control_period_ns / 1e6
    if settings.heartbeat_timeout_ms < 2 * spacing_ms:
        return (f"heartbeat_timeout_ms = {settings.heartbeat_timeout_ms} is shorter than two "
                f"heartbeats ({settings.heartbeat_periods} periods of "
                f"{control_period_ns / 1e6:g} ms each = {spacing_ms:g} ms apart)")
    return None
