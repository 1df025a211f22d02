"""Configuration of the core: everything a replay or a live run fixes before the first event."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from assurance.cartesian import CartesianMapper
from assurance.collision import CellCollision
from assurance.handshake import AllowList, ClientHello, Session
from assurance.kinematics import ArmKinematics, WorkspaceBox
from assurance.limits import JointLimits
from assurance.plausibility import Tolerances
from assurance.reasons import ReasonCode
from assurance.watermarks import WatermarkConfig
from skills.contact import ContactConfig
from skills.phases import PhaseBook, TaskPhase


@dataclass(frozen=True, slots=True)
class ClientSide:
    """What this client states in its handshake (docs/contract.md §5), minus the queue epoch."""

    skill: str
    skill_version: str
    observation_keys: tuple[str, ...]
    action_dim: int
    action_units: str
    action_frame: str
    controller_mode: str
    calibration_epoch: str
    protocol: tuple[int, int]
    control_rate_hz: float

    def hello(self, queue_epoch: int) -> ClientHello:
        return ClientHello(
            skill=self.skill, skill_version=self.skill_version,
            observation_keys=self.observation_keys, action_dim=self.action_dim,
            action_units=self.action_units, action_frame=self.action_frame,
            controller_mode=self.controller_mode, control_rate_hz=self.control_rate_hz,
            calibration_epoch=self.calibration_epoch, queue_epoch=queue_epoch,
            protocol=self.protocol, reason_codes=tuple(ReasonCode),
        )


@dataclass(frozen=True, slots=True, eq=False)
class MotionConfig:
    """How the core shapes what reaches the arm (the ``motion`` section; all optional)."""

    interpolator_jerk: float = 50.0
    """rad/s³ per joint: the setpoint interpolator's jerk limit (policy streams, holds)."""
    planner_velocity: float = 2.0
    """rad/s: the planner's classical moves go no faster (nor above the robot's limit)."""
    planner_acceleration: float = 6.0
    """rad/s²: the planner's acceleration (nor above the robot's limit)."""
    planner_jerk: float = 60.0
    """rad/s³: the planner's jerk."""
    impedance: bool = True
    """The device takes compliant (impedance) targets from the contact owner; if not, the
    contact owner's targets go out as position setpoints."""
    contact: ContactConfig = field(default_factory=ContactConfig)

    def __post_init__(self) -> None:
        for name in ("interpolator_jerk", "planner_velocity", "planner_acceleration",
                     "planner_jerk"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"motion.{name} must be positive and finite, got {value}")


@dataclass(frozen=True, slots=True, eq=False)
class TrialBounds:
    """The envelope of a bounded trial that the core enforces itself (the ``envelope``
    section): the tool stays in the box, commanded and measured, and the wrist force stays
    below its limit; otherwise ENVELOPE stops the arm."""

    workspace: WorkspaceBox
    max_force_n: float


class LossAction(StrEnum):
    """What losing a camera means (``[[cameras]] on_loss``)."""

    STOP = "stop"
    """The phase stops at once: SAFE_HOLD (CAMERA_LOST)."""
    CONTINUE = "continue"
    """The arm finishes what was admitted while the camera saw, and no new observation goes
    out; not back within ``grace``, the phase stops as with ``stop``."""


@dataclass(frozen=True, slots=True)
class CameraLoss:
    """One camera the policy sees through, as the core knows it: its name and what losing it
    means."""

    name: str
    on_loss: LossAction = LossAction.STOP
    grace_ns: int = 0
    """``continue`` only: how long the arm may go on without it."""


@dataclass(frozen=True, slots=True, eq=False)
class CoreConfig:
    limits: JointLimits
    control_period_ns: int
    clock_uncertainty_ns: int
    phases: PhaseBook
    client: ClientSide
    allowlist: AllowList
    initial_session: Session | None
    initial_phase: TaskPhase
    initial_q: np.ndarray
    initial_epoch: int = 0
    watermarks: WatermarkConfig = field(default_factory=WatermarkConfig)
    degrade_after: int = 3
    """Consecutive timing refusals (stale, expired, reordered, ...) before DEGRADED."""
    state_timeout_ns: int | None = None
    """Watchdog on state samples; ``None`` disables it (scenario default)."""
    memory_capacity: int = 4096
    cartesian: CartesianMapper | None = None
    """Maps Cartesian chunks to joint targets; set exactly when the session's frame is
    Cartesian (``base_delta``)."""
    kinematics: ArmKinematics | None = None
    """The arm's kinematic model, where the robot names one: the contact owner's descents
    need it (without it, contact is a compliant hold)."""
    motion: MotionConfig = field(default_factory=MotionConfig)
    envelope: TrialBounds | None = None
    """A trial's envelope (needs ``kinematics`` for the workspace box); None: no trial."""
    plausibility: Tolerances = field(default_factory=Tolerances)
    """The noise and timing a state sample may carry and still be judged plausible."""
    collision: CellCollision | None = None
    """The cell's geometry (``[geometry]``): every chunk's actions, and the motion between
    them, keep their clearance from the cell's solids and the arm's own links (COLLISION);
    None: no geometry, no such check."""
    cameras: tuple[CameraLoss, ...] = ()
    """The cameras observations carry (the ``cameras`` section): losing one stops the phase,
    at once or after its grace (:mod:`kernel.core.cameras`)."""

    def __post_init__(self) -> None:
        if self.control_period_ns <= 0:
            raise ValueError("control period must be positive")
        if self.initial_q.shape != (self.limits.dim,):
            raise ValueError(
                f"initial state has {self.initial_q.shape[0]} values, robot has {self.limits.dim}"
            )
