"""The driver contract, the messages that cross it, and the errors a driver may raise.

A driver implements hooks only (:class:`Driver` declares every one, the optional ones with
defaults, and what each lifecycle state allows). :class:`drivers.lifecycle.ManagedDriver` owns
the state machine (UNCONFIGURED → INACTIVE → ACTIVE → FAULT/CLOSED), calls ``write`` only when
ACTIVE, turns any exception into FAULT with a reason code, and times every call. ``write``
returns what the device actually applied (after its own clipping), never what was asked.

Blocking vendor SDK calls run on one dedicated thread per device: see
:class:`drivers.device_thread.DeviceThread`. Nothing here runs on the event loop thread for longer
than it takes to hand a call over.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, ClassVar, Self

import msgspec

from assurance.reasons import ReasonCode
from drivers.readiness import Finding
from drivers.settings import Settings, read_table


class DriverState(StrEnum):
    UNCONFIGURED = "UNCONFIGURED"
    INACTIVE = "INACTIVE"
    ACTIVE = "ACTIVE"
    FAULT = "FAULT"
    CLOSED = "CLOSED"


class CommandKind(StrEnum):
    POSITION = "position"
    """Stream a joint position setpoint (servoJ, goal position, CSP target)."""
    VELOCITY = "velocity"
    """Stream a joint velocity (speedJ); not every driver supports it."""
    HOLD = "hold"
    """Hold the joints where they are now, with the device's own position loop."""
    STOP = "stop"
    """Decelerate to standstill and stop streaming (stopJ, quick stop, torque kept on).
    Any later POSITION or HOLD resumes from where the stop left the arm: the core sends one
    only once an operator accepted recovery, and starts it there (its interpolator restarts
    from the measured position every STOP tick). A device that must be enabled again first
    (a CiA 402 drive in QUICK STOP ACTIVE) is enabled by the driver, its target first set to
    where the arm rests, never refused: the core would only stop the arm again."""
    IMPEDANCE = "impedance"
    """Compliant joint-space target with per-joint stiffness and damping (the contact owner).
    A driver that cannot do it refuses the command (CONTROLLER_MODE_MISMATCH)."""


class StateSample(msgspec.Struct, frozen=True, kw_only=True):
    """One measured state of the device, in SI units (rad, rad/s, N·m, N, m)."""

    seq: int
    t_mono_ns: int
    source: str
    q: tuple[float, ...]
    qd: tuple[float, ...] = ()
    effort: tuple[float, ...] = ()
    wrench: tuple[float, ...] = ()
    gripper: float | None = None
    speed_scaling: float = 1.0
    faults: tuple[ReasonCode, ...] = ()
    """Reason codes the device reports right now (E_STOP, CONTROLLER_FAULT, ...)."""


class Command(msgspec.Struct, frozen=True, kw_only=True):
    kind: CommandKind
    q: tuple[float, ...] = ()
    qd: tuple[float, ...] = ()
    stiffness: tuple[float, ...] = ()
    damping: tuple[float, ...] = ()
    gripper: float | None = None
    """Gripper opening in metres; None leaves the gripper as it is."""
    seq: int = 0


class Applied(msgspec.Struct, frozen=True, kw_only=True):
    """What reached the device. ``accepted`` is False when the device refused the command."""

    kind: CommandKind
    t_mono_ns: int
    q: tuple[float, ...] = ()
    qd: tuple[float, ...] = ()
    accepted: bool = True
    reason: ReasonCode | None = None


class NoSettings(Settings, frozen=True):
    """The settings of a driver whose ``[driver]`` table takes no keys (the sim driver)."""


@dataclass(frozen=True, slots=True)
class ControlConfig:
    """What every driver needs to know about the control loop that will drive it."""

    dof: int
    period_ns: int
    q_lower: tuple[float, ...]
    q_upper: tuple[float, ...]
    v_max: tuple[float, ...]
    a_max: tuple[float, ...] = ()
    """Acceleration limits (rad/s²); empty: not given (a driver then judges its readings'
    plausibility by the velocity limits alone, :mod:`drivers.plausible`)."""


class Driver(abc.ABC):
    """The driver contract: every hook a driver may implement, in one place.

    A driver subclasses this class, implements the required hooks, and overrides an optional
    hook only to do more than its default. Nothing is looked up by name at run time: whatever
    the kernel calls is declared here.

    **Declarations** (class attributes):

    - ``settings_type``: the frozen type of the driver's manifest ``[driver]`` table (the
      table minus ``name``). :func:`drivers.registry.settings_for` decodes the table into it
      once, when the manifest is loaded; unknown keys and values out of bounds are refused
      there, naming the key.
    - ``capabilities``: the command kinds the device executes. The lifecycle refuses any
      other kind with CONTROLLER_MODE_MISMATCH before it reaches the driver, and the core
      sends compliant targets as IMPEDANCE only to a driver that lists it (else as POSITION).
      ``drivers.testing.check_capabilities`` checks the declaration against behaviour.
    - ``address_keys``: the settings that say where the device is, each with a placeholder: a
      run that launches its own emulator fills them in from it, so such a manifest may leave
      them out (they are checked with the placeholder).

    **Construction**: ``from_mapping(table, where, name=...)`` (one signature for every
    driver) decodes a table and calls ``from_settings(settings, name)``.

    **Declarations about the device, per settings** (static methods, default: none):
    ``device_watchdog`` (what stops the arm when warden's commands stop), ``device_watchdog_ms``
    (how long after warden's last command it does) and ``device_identity`` (the device the
    settings address, one string shared by every table that names the same device: warden
    locks it before touching the device, so two wardens never drive one device).

    **Lifecycle** (:class:`drivers.lifecycle.ManagedDriver` owns it, as ros2_control's
    hardware component does; a driver never tracks these states itself):

    ============  =================================================================
    state         what the lifecycle calls on the driver
    ============  =================================================================
    UNCONFIGURED  ``connect`` then ``configure`` (→ INACTIVE); ``aclose``
    INACTIVE      ``read``, ``hold``, ``activate`` (→ ACTIVE), ``inspect``; ``aclose``
    ACTIVE        ``before_first_tick`` (once, before the loop's timer starts), ``read``,
                  ``write`` (a kind in ``capabilities`` only), ``hold``,
                  ``deactivate`` (→ INACTIVE); ``aclose`` (after ``deactivate``)
    FAULT         nothing but ``aclose``: reads answer the last sample marked with the
                  fault, writes and holds are refused without a call
    CLOSED        nothing (``aclose`` again is a no-op)
    ============  =================================================================

    Any exception from a hook turns the driver to FAULT with the error's reason code
    (:class:`DriverError`; anything else: CONTROLLER_FAULT).
    """

    settings_type: ClassVar[type[Any]] = NoSettings
    capabilities: ClassVar[frozenset[CommandKind]] = frozenset(
        {CommandKind.POSITION, CommandKind.HOLD, CommandKind.STOP})
    address_keys: ClassVar[Mapping[str, Any]] = {}
    default_name: ClassVar[str] = "driver"
    """The name a driver built without one gets (its registry name)."""

    name: str

    # -- construction -------------------------------------------------------------------------

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any], where: str | None = None, *,
                     name: str | None = None) -> Self:
        """Build from a manifest ``[driver]`` table (without ``name``).

        Raises:
            SettingsError: naming ``where.key`` (default ``drivers.<name>``).
        """
        where = where or f"drivers.{name or cls.default_name}"
        return cls.from_settings(read_table(cls.settings_type, table, where), name)

    @classmethod
    def from_settings(cls, settings: Any, name: str | None = None) -> Self:
        """Build from decoded settings (``settings_type``); the default calls ``cls(settings,
        name)``."""
        return cls(settings, name or cls.default_name)  # type: ignore[call-arg]

    # -- declarations about the device --------------------------------------------------------

    @staticmethod
    def device_watchdog(settings: Any) -> str | None:
        """What stops the arm when warden's commands stop, as ``settings`` configure it;
        None: nothing (switched off, or the device has none)."""
        return None

    @staticmethod
    def device_watchdog_ms(settings: Any, control_period_ms: float) -> float | None:
        """How long after warden's last command :meth:`device_watchdog` stops the arm, in ms;
        None: not declared."""
        return None

    @staticmethod
    def device_identity(settings: Any) -> str | None:
        """The device ``settings`` address; None: nothing another process can reach."""
        return None

    # -- required hooks -----------------------------------------------------------------------

    @abc.abstractmethod
    async def connect(self) -> None:
        """Open the link and check the device is the one the settings describe."""

    @abc.abstractmethod
    async def configure(self, control: ControlConfig) -> None:
        """Fit the device to the control loop (period, limits); nothing moves."""

    @abc.abstractmethod
    async def activate(self) -> None:
        """Make the device follow setpoints from where it is."""

    @abc.abstractmethod
    async def read(self) -> StateSample:
        """One fresh sample; a fault the device reports raises :class:`DeviceFault`."""

    @abc.abstractmethod
    async def write(self, command: Command) -> Applied:
        """Send ``command`` (its kind is one of ``capabilities``); return what was applied."""

    @abc.abstractmethod
    async def hold(self) -> Applied:
        """Hold the joints where they are (ACTIVE and INACTIVE)."""

    @abc.abstractmethod
    async def deactivate(self) -> None:
        """Stop following setpoints; the device keeps the arm where it is."""

    @abc.abstractmethod
    async def aclose(self) -> None:
        """Release every resource. Safe to call twice; releases even when a step fails."""

    # -- optional hooks -----------------------------------------------------------------------

    async def before_first_tick(self) -> None:
        """Called once in ACTIVE right before the control loop's timer starts, for the one
        blocking step that must come just before the first setpoint (the UR driver arms the
        controller's RTDE watchdog there: inside the first tick its 20-100 ms round trip was
        a stall of the loop). Default: nothing to do."""
        return None

    async def inspect(self) -> tuple[Finding, ...] | None:
        """Read the device's own configuration (modes, limits, calibration) and compare it
        with the settings, one :class:`Finding` per comparison, reads only (``warden check``).
        None (the default): the driver offers no inspection.

        Raises:
            DriverError: the device could not be read.
        """
        return None


# ---------------------------------------------------------------------------------------------
# Errors: each carries the reason code the lifecycle records when it turns the driver to FAULT.
# ---------------------------------------------------------------------------------------------


class DriverError(Exception):
    """Base of driver errors: a message for humans, a reason code for machines."""

    default_reason = ReasonCode.CONTROLLER_FAULT

    def __init__(self, device: str, message: str, reason: ReasonCode | None = None) -> None:
        super().__init__(f"{device}: {message}")
        self.device = device
        self.reason = reason or self.default_reason


class DriverInitError(DriverError):
    """The device could not be reached or configured (wrong port, host, baud rate, version)."""


class DriverIOError(DriverError):
    """A read or write failed on an established link."""

    default_reason = ReasonCode.LINK_LOST


class DriverTimeout(DriverError, TimeoutError):
    """A device call did not return within its deadline."""

    default_reason = ReasonCode.WATCHDOG


class NotConnected(DriverError, ConnectionError):
    """A call that needs a connection was made without one."""

    default_reason = ReasonCode.LINK_LOST


class DeviceFault(DriverError):
    """The device itself reports a fault: protective stop, e-stop, hardware error."""
