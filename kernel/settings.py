"""The settings tables of a manifest that only a live run needs, as frozen dataclasses.

:mod:`kernel.manifest` reads them (every key known, every value typed and range-checked); they
are here so each table's meaning can be read on its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

# [emulator] is read by the safety monitor too, so its type lives below both readers.
from kernel.manifest_tables import EmulatorSettings as EmulatorSettings
from kernel.manifest_tables import PlantKind as PlantKind
from kernel.wire import MAX_FRAME_BYTES


class ClockKind(StrEnum):
    WALL = "wall"
    """Real time: a kernel timer paces the control loop; the policy server is a process."""
    VIRTUAL = "virtual"
    """Lockstep: a virtual clock, the plant and an in-process policy step together (fast)."""


@dataclass(frozen=True, slots=True)
class CellSettings:
    cycles: int = 3
    clock: ClockKind = ClockKind.WALL
    seed: int = 7
    cycle_timeout_s: float = 30.0
    insertion_tolerance_m: float = 0.015
    """The evaluator's bar: peg depth below the fixture's top face that counts as inserted."""
    ground_truth: bool = True
    """In simulation, VERIFY also asks the simulator how deep the part truly is, and passes only
    if that agrees with the measured evidence. False: the measured evidence alone decides, as
    on a real cell (which has no ground truth whatever this says)."""
    simulated_operator: bool = True
    """Accept recovery automatically once the arm rests under a fallback owner. Simulation
    only: a manifest that drives a real device must set it false (a human recovers)."""


POLICY_LINK_BOUNDS: dict[str, tuple[float, float]] = {
    "max_frames_per_s": (1.0, 100_000.0),
    "max_chunks_per_s": (0.1, 10_000.0),
    "max_requests_in_flight": (1, 64),
    "admissions_per_period": (1, 64),
    "request_timeout_ms": (1.0, 60_000.0),
    "heartbeat_interval_ms": (1.0, 60_000.0),
    "heartbeat_timeout_ms": (1.0, 60_000.0),
}
"""Ranges of what one policy peer may cost (docs/manifest.md, "Bounds"): every rate, count and
time the link budget (kernel/shell/link_budget.py) computes with is finite and sane before a
server starts. A frame rate above 100 000/s or a chunk rate above 10 000/s is no limit at the
GIL's pace; more than 64 requests in flight or admissions per period is more than a chunk
queue holds; a timeout or heartbeat beyond a minute is a dead link nobody notices."""


def _check_bounded(name: str, value: float, low: float, high: float) -> None:
    """``value`` is a finite number within [low, high] (NaN and ±inf refused by name)."""
    if not value > 0:  # also refuses NaN
        raise ValueError(f"{name} must be positive, got {value!r}")
    if not (math.isfinite(value) and value <= high):
        raise ValueError(f"{name} must be a finite number of at most {high:g}, got {value!r}")
    if value < low:
        raise ValueError(f"{name} must be at least {low:g}, got {value!r}")


@dataclass(frozen=True, slots=True)
class PolicySettings:
    launch: bool = True
    host: str = "127.0.0.1"
    expose: bool = False
    """A launched reference server may listen on a ``host`` that is not loopback (reachable
    from other hosts: the link has no authentication). Off: such a host is refused."""
    port: int = 0
    latency_median_ms: float = 30.0
    latency_p95_ms: float = 60.0
    chunk_horizon: int = 20
    action_dt_ms: float = 20.0
    noise_rad: float = 0.0005
    clock_offset_ms: float = 0.0
    # What one policy peer may cost (docs/manifest.md, [policy]; kernel/shell/link_budget.py)
    max_frame_bytes: int = 65536
    max_frames_per_s: float = 1000.0
    max_chunks_per_s: float = 100.0
    max_requests_in_flight: int = 4
    request_timeout_ms: float = 250.0
    admissions_per_period: int = 1
    heartbeat_interval_ms: float = 100.0
    heartbeat_timeout_ms: float = 350.0

    def __post_init__(self) -> None:
        for name, (low, high) in POLICY_LINK_BOUNDS.items():
            _check_bounded(name, getattr(self, name), low, high)
        if not 1 <= self.max_frame_bytes <= MAX_FRAME_BYTES:
            raise ValueError(f"max_frame_bytes must be in 1..{MAX_FRAME_BYTES}, got "
                             f"{self.max_frame_bytes!r}")
        if not self.heartbeat_timeout_ms > self.heartbeat_interval_ms:
            raise ValueError(f"heartbeat_timeout_ms ({self.heartbeat_timeout_ms!r}) must be "
                             f"longer than heartbeat_interval_ms ({self.heartbeat_interval_ms})")

    @property
    def link_loss_bound_ms(self) -> float:
        """How long a dead link may go unnoticed, with one heartbeat of margin."""
        return self.heartbeat_timeout_ms + self.heartbeat_interval_ms


@dataclass(frozen=True, slots=True)
class OperatorSettings:
    """``[operator]``: the socket a human commands the running arm through."""

    socket: str = ""
    """Its path; empty: ``$RUNTIME_DIRECTORY/operator.sock`` under systemd, else
    ``/run/warden/operator.sock``."""
    group: str = ""
    """Who may command: members of this group (and root); empty: warden's own group."""


@dataclass(frozen=True, slots=True)
class JournalSettings:
    enabled: bool = True
    directory: str = "runs"


@dataclass(frozen=True, slots=True)
class TrialEnvelope:
    """``[trial]``: every bound of a bounded trial, all of them required."""

    max_cycles: int
    max_duration_s: float
    workspace_lower: tuple[float, float, float]
    """The box the tool (TCP) must stay in, base frame, metres: its lower corner..."""
    workspace_upper: tuple[float, float, float]
    """...and its upper corner."""
    speed_scale: float
    """Every joint's velocity limit is multiplied by this (0 < scale <= 1)."""
    max_wrist_force_n: float
