"""The driver protocol, the messages that cross it, and the errors a driver may raise.

A driver implements hooks only. :class:`drivers.lifecycle.ManagedDriver` owns the state machine
(UNCONFIGURED → INACTIVE → ACTIVE → FAULT/CLOSED), calls ``write`` only when ACTIVE, turns any
exception into FAULT with a reason code, and times every call. ``write`` returns what the device
actually applied (after its own clipping), never what was asked.

Blocking vendor SDK calls run on one dedicated thread per device: see
:class:`drivers.device_thread.DeviceThread`. Nothing here runs on the event loop thread for longer
than it takes to hand a call over.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Protocol, runtime_checkable

import msgspec

from assurance.reasons import ReasonCode


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
    """Decelerate to standstill and stop streaming (stopJ, quick stop, torque kept on)."""
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


@dataclass(frozen=True, slots=True)
class ControlConfig:
    """What every driver needs to know about the control loop that will drive it."""

    dof: int
    period_ns: int
    q_lower: tuple[float, ...]
    q_upper: tuple[float, ...]
    v_max: tuple[float, ...]


@runtime_checkable
class Driver(Protocol):
    """The hooks a device driver implements. Device settings come to the constructor.

    A driver class may also declare, as static methods of a manifest ``[driver]`` table:
    ``device_watchdog(table) -> str | None`` (what stops the arm when warden's commands stop)
    and ``device_identity(table) -> str | None`` (the device the table addresses, one string
    shared by every table that names the same device: warden takes a lock on it before touching
    the device, so two wardens never drive one device; None: nothing another process can reach).

    Optional hook: ``async def before_first_tick(self) -> None``, called once in ACTIVE right
    before the control loop's timer starts, for the one blocking step that must come just
    before the first setpoint (the UR driver arms the controller's RTDE watchdog there: done
    inside the first tick, its round trip of 20-100 ms was a stall of the loop).
    """

    name: str

    async def connect(self) -> None: ...

    async def configure(self, control: ControlConfig) -> None: ...

    async def activate(self) -> None: ...

    async def read(self) -> StateSample: ...

    async def write(self, command: Command) -> Applied: ...

    async def hold(self) -> Applied: ...

    async def deactivate(self) -> None: ...

    async def aclose(self) -> None:
        """Release every resource. Safe to call twice; releases even when a step fails."""
        ...


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
