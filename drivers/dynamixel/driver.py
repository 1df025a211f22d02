"""Driver for a chain of Dynamixel X-series servos on one serial port (Protocol 2.0).

Hooks only: :class:`drivers.lifecycle.ManagedDriver` owns the state machine. Every SDK call goes
through one :class:`drivers.device_thread.DeviceThread` per port, because the SDK's port is not
thread-safe and its calls block (and spin) while they wait for a reply.

- connect: open the port at ``baud``, ping every configured id (a missing one is named), check
  the model numbers, and pick Fast Sync Read when the servos answer it (else Sync Read).
- configure: torque off, position mode.
- activate: Bus Watchdog cleared (off, and out of a Bus Watchdog Error a previous run left),
  goals := present positions, then torque on. deactivate: hold (unless nothing was written
  since activation: the goals set then still hold the arm, and a goal write with torque on is
  a motion command), Bus Watchdog off, torque stays on (an arm under gravity must not drop
  because streaming stopped). aclose: torque off, port closed.
- inspect (``warden check``): the control table against the settings and the manifest's
  limits, reads only (:mod:`drivers.dynamixel.inspection`).
- Bus Watchdog (``watchdog_periods``): the first position setpoint after activation arms it
  on every servo with one broadcast (the kernel's bring-up sends nothing for longer than a
  watchdog between activation and its first tick); every packet feeds it; when it expires the
  servos stop on their own, and the next read reports WATCHDOG.
- read: one (fast) sync read of present current, velocity and position; the alert bit in any
  status packet turns into a DeviceFault that names the hardware error bits.
- write: one sync write of goal positions, clipped to the joint limits and the one-turn range.
  HOLD writes the joints' last goals again, never a reading (a glitched one would be a goal
  the arm moves to); STOP makes the present position the goal once (from a plausible reading
  only, else the last plausible one: ``drivers.plausible``), then holds it.

With ``gripper_id`` one more servo on the bus is the gripper: bring-up finds and configures it
with the joints; a POSITION command's ``gripper`` opening (m, clipped to [0, 0.085]) goes out in
the joints' sync write, and ``None`` leaves it alone; HOLD and STOP hold the joints only (a
gripper holding a part keeps squeezing); ``read`` reports its opening in ``StateSample.gripper``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from typing import ClassVar, TypeVar

import msgspec
import structlog

from assurance.reasons import ReasonCode
from drivers.base import (
    Applied,
    Command,
    CommandKind,
    ControlConfig,
    Driver,
    DriverError,
    DriverInitError,
    NotConnected,
    StateSample,
)
from drivers.device_thread import DeviceThread
from drivers.dynamixel import inspection
from drivers.dynamixel import settings as settings_module
from drivers.dynamixel.bus import DynamixelBus, RawState
from drivers.dynamixel.settings import GRIPPER_MAX_OPENING_M, DynamixelSettings
from drivers.dynamixel.tables import POSITION_MODE_TICKS
from drivers.dynamixel.units import GripperCalibration, JointCalibration
from drivers.plausible import LastPlausible
from drivers.readiness import Finding

T = TypeVar("T")
log = structlog.get_logger(__name__)


class DynamixelDriver(Driver):
    settings_type = DynamixelSettings
    capabilities = frozenset({CommandKind.POSITION, CommandKind.HOLD, CommandKind.STOP})
    """Position mode only: no VELOCITY (Operating Mode 1) and no IMPEDANCE (the servos have
    no joint-space compliance), so compliant targets go out as positions."""
    address_keys: ClassVar[Mapping[str, str]] = settings_module.ADDRESS_KEYS
    default_name = "dynamixel"
    device_watchdog = staticmethod(settings_module.device_watchdog)
    """What stops the arm when warden's commands stop, per manifest table (None: off)."""
    device_identity = staticmethod(settings_module.device_identity)
    """The device a manifest table addresses (one warden per device: kernel/shell/device_lock)."""
    device_watchdog_ms = staticmethod(settings_module.device_watchdog_ms)
    """...and how long after warden's last command it does, in ms."""

    def __init__(self, settings: DynamixelSettings, name: str = "dynamixel") -> None:
        self.name = name
        self.settings = settings
        self.calibration = JointCalibration(
            offsets=settings.offsets_rad, directions=settings.directions,
            current_unit_a=settings.current_unit_ma / 1000.0,
            torque_per_amp=settings.torque_per_amp_nm,
        )
        self.gripper = GripperCalibration(settings.gripper_open_ticks,
                                          settings.gripper_closed_ticks, GRIPPER_MAX_OPENING_M)
        self._tick_lower, self._tick_upper = self.calibration.q_range(*POSITION_MODE_TICKS)
        self._lower, self._upper = self._tick_lower, self._tick_upper
        self._watchdog_units = 0
        self._control: ControlConfig | None = None
        self._written = False
        """A goal went out since activation (deactivate then holds where the arm is)."""
        self._stopped = False
        """A STOP made the present position the goal, and no setpoint went out since."""
        self._thread: DeviceThread | None = None
        self._bus: DynamixelBus | None = None
        self._seq = 0
        self._readings = LastPlausible()
        """Every reading, judged as the core judges its samples: a STOP's goal is taken from a
        plausible one only."""

    @property
    def bus(self) -> DynamixelBus | None:
        """The connected bus (counters, fast-read choice), for diagnostics and benchmarks."""
        return self._bus

    # ------------------------------------------------------------------ lifecycle hooks

    async def connect(self) -> None:
        if self._bus is not None:
            return
        thread = DeviceThread(f"{self.name}:{self.settings.port}")
        bus = DynamixelBus(self.settings, self.name)
        try:
            await thread.run(self.settings.call_timeout_s, bus.connect)
        except BaseException:
            bus.abandon()
            thread.close()
            raise
        self._thread, self._bus = thread, bus
        log.info("dynamixel.connected", device=self.name, port=self.settings.port,
                 models=bus.models, fast_sync_read=bus.uses_fast_sync_read,
                 low_latency=bus.low_latency)

    async def configure(self, control: ControlConfig) -> None:
        if control.dof != len(self.settings.ids):
            raise DriverInitError(self.name, f"the control loop has {control.dof} joints but "
                                  f"`ids` lists {len(self.settings.ids)} servos; check `ids`")
        try:
            self._watchdog_units = self.settings.watchdog_units(control.period_ns * 1e-9)
        except ValueError as error:
            raise DriverInitError(self.name, f"{self.settings.port}: {error}") from error
        bus = self._connected_bus()
        await self._run(bus.prepare_position_mode)
        self._lower = tuple(map(max, control.q_lower, self._tick_lower))
        self._upper = tuple(map(min, control.q_upper, self._tick_upper))
        self._control = control
        self._readings.configure(control)

    async def activate(self) -> None:
        bus = self._connected_bus()
        if self._watchdog_units:
            await self._run(bus.clear_watchdogs)
        await self._run(bus.enable_torque_holding)
        self._written = self._stopped = False

    async def read(self) -> StateSample:
        raw = await self._run(self._connected_bus().read_state)
        return self._sample(raw)

    async def write(self, command: Command) -> Applied:
        if command.kind is CommandKind.POSITION:
            return await self._write_position(command)
        if command.kind is CommandKind.STOP and not self._stopped:
            return await self._stop_here()
        if command.kind in (CommandKind.HOLD, CommandKind.STOP):
            # Its gripper opening is ignored on purpose: a hold must never open the gripper.
            applied = await self.hold()
            return msgspec.structs.replace(applied, kind=command.kind)
        # The servos run in position mode; velocity streaming would need Operating Mode 1.
        return _refused(command.kind, ReasonCode.CONTROLLER_MODE_MISMATCH)

    async def _stop_here(self) -> Applied:
        """A stop ends motion now: goal := where the servo is, read once (a far goal is not
        followed on) and believed only if plausible, else the last plausible reading: a
        glitched one is a goal the arm moves to. Repeated, as every tick of E_STOP sends it,
        the goal stays (re-read each time, the arm would chase a glitch)."""
        self._written = self._stopped = True
        bus = self._connected_bus()
        raw = await self._run(bus.read_state)
        q = self.calibration.q_from_ticks(raw.position)
        qd = self.calibration.qd_from_units(raw.velocity)
        here = self._readings.believed(time.monotonic_ns(), q, qd)
        goals = raw.position if here is None or here == q else self._ticks_in_range(here)
        await self._run(bus.write_goals, goals)
        return Applied(kind=CommandKind.STOP, t_mono_ns=time.monotonic_ns(),
                       q=self.calibration.q_from_ticks(goals))

    async def hold(self) -> Applied:
        self._written = True
        goals = await self._run(self._connected_bus().hold_at_goals)
        return Applied(kind=CommandKind.HOLD, t_mono_ns=time.monotonic_ns(),
                       q=self.calibration.q_from_ticks(goals))

    async def deactivate(self) -> None:
        if self._bus is not None:
            if self._written:
                await self.hold()
            if self._watchdog_units:
                await self._run(self._bus.clear_watchdogs)

    async def inspect(self) -> tuple[Finding, ...] | None:
        """The control table against the settings and limits (reads only; after configure)."""
        bus = self._connected_bus()
        if self._control is None:
            raise NotConnected(self.name, f"{self.settings.port}: inspect needs configure first")
        servos = await self._run(inspection.read_configuration, bus)
        raw = await self._run(bus.read_state)
        gripper = None if raw.gripper is None else self.gripper.opening_from_ticks(raw.gripper)
        return inspection.findings(inspection.Inspected(
            self.settings, self.calibration, self._control, bus.models, servos, gripper,
            self._watchdog_units))

    async def aclose(self) -> None:
        """Torque off and close the port. Safe to call twice; releases even when a step fails."""
        thread, bus = self._thread, self._bus
        self._thread = self._bus = None
        if thread is None or bus is None:
            return
        try:
            await thread.run(self.settings.call_timeout_s, bus.release)
        except DriverError as error:
            log.warning("dynamixel.release_failed", device=self.name, error=str(error))
            bus.abandon()  # the worker may still be stuck in the SDK
        finally:
            thread.close()

    # ------------------------------------------------------------------ helpers

    async def _write_position(self, command: Command) -> Applied:
        if len(command.q) != len(self.settings.ids):
            return _refused(command.kind, ReasonCode.MALFORMED)
        if not all(math.isfinite(v) for v in (*command.q, command.gripper or 0.0)):
            return _refused(command.kind, ReasonCode.NONFINITE)
        q = tuple(min(max(v, lo), hi)
                  for v, lo, hi in zip(command.q, self._lower, self._upper, strict=True))
        ticks = self._ticks_in_range(q)
        bus = self._connected_bus()
        if self._watchdog_units and not bus.watchdog_units:  # the first setpoint arms it
            await self._run(bus.arm_watchdogs, self._watchdog_units)
        self._written, self._stopped = True, False
        await self._run(bus.write_goals, ticks, self._gripper_tick(command))
        # ``q`` is what was sent before rounding to whole ticks (at most half a tick, 0.77 mrad).
        return Applied(kind=command.kind, t_mono_ns=time.monotonic_ns(), q=q)

    def _gripper_tick(self, command: Command) -> int | None:
        """The gripper's goal tick, or None to leave it (no opening asked, or no gripper)."""
        if command.gripper is None or self.settings.gripper_id is None:
            return None
        return self.gripper.ticks_from_opening(command.gripper)

    def _ticks_in_range(self, q: tuple[float, ...]) -> tuple[int, ...]:
        low, high = POSITION_MODE_TICKS
        return tuple(min(max(t, low), high) for t in self.calibration.ticks_from_q(q))

    def _sample(self, raw: RawState) -> StateSample:
        self._seq += 1
        t, q = time.monotonic_ns(), self.calibration.q_from_ticks(raw.position)
        qd = self.calibration.qd_from_units(raw.velocity)
        self._readings.judge(t, q, qd)
        return StateSample(
            seq=self._seq, t_mono_ns=t, source=self.name, q=q, qd=qd,
            effort=self.calibration.effort_from_units(raw.current),
            gripper=None if raw.gripper is None else self.gripper.opening_from_ticks(raw.gripper),
        )

    def _connected_bus(self) -> DynamixelBus:
        if self._bus is None:
            raise NotConnected(self.name, f"{self.settings.port} is not open: connect first")
        return self._bus

    async def _run(self, fn: Callable[..., T], *args: object) -> T:
        if self._thread is None:
            raise NotConnected(self.name, f"{self.settings.port} is not open: connect first")
        return await self._thread.run(self.settings.call_timeout_s, fn, *args)


def _refused(kind: CommandKind, reason: ReasonCode) -> Applied:
    return Applied(kind=kind, t_mono_ns=time.monotonic_ns(), accepted=False, reason=reason)
