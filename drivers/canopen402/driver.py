"""CiA 402 servo drives on CANopen (canopen ``BaseNode402``, one node per joint), in CSP mode,
and optionally one more such drive for the gripper (:mod:`drivers.canopen402.gripper`).

connect: open the bus, NMT pre-operational, check every node answers and is a 402 drive, start
its heartbeat, set its reaction to a lost connection, refuse (or, if allowed, reset) a drive in
FAULT. configure: cycle time, limits, quick-stop option and PDO mapping over SDO, NMT
operational, the bus cycle (RPDOs + SYNC) at the control period, CSP confirmed. activate:
target := actual, then up to OPERATION ENABLED. write: targets into the RPDOs, then RPDOs +
SYNC; right before the loop's first tick (or at the first setpoint) every drive's watchdog on
warden's heartbeat is armed, which every write then feeds (:mod:`drivers.canopen402.watchdog`).
read: the latest TPDOs, converted to SI units.
HOLD keeps the targets (where each command puts them: :mod:`drivers.canopen402.targets`). STOP
is a quick stop (QUICK STOP ACTIVE); the next POSITION or HOLD (the core's first command after
an accepted recovery) sets the targets where the stop left the drives and enables them again,
then goes out as usual. deactivate: the same hold, then disable.
inspect (``warden check``): each drive's objects against the settings, reads only.
Every step that concerns "every drive" includes the gripper drive, so its faults surface exactly
as a joint's do; only the units and the HOLD/STOP rules differ.

Blocking canopen calls (SDO, waits for a TPDO) run on the device thread only: on the loop thread
they would wait for a frame that the loop itself has to dispatch.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable, Mapping
from typing import ClassVar, TypeVar

import can
import msgspec

from assurance.reasons import ReasonCode
from drivers.base import (
    Applied,
    Command,
    CommandKind,
    ControlConfig,
    Driver,
    DriverInitError,
    DriverIOError,
    DriverTimeout,
    NotConnected,
    StateSample,
)
from drivers.canopen402 import bringup, gripper, inspection, parameters, watchdog
from drivers.canopen402 import settings as settings_module
from drivers.canopen402._sdk import Node402
from drivers.canopen402.cycle import BusCycle
from drivers.canopen402.drive_state import FAULTY, current_state, walk_to
from drivers.canopen402.gripper import Gripper
from drivers.canopen402.health import HealthMonitor
from drivers.canopen402.link import Link, build_link
from drivers.canopen402.process_data import joint_readings, start_bus_cycle
from drivers.canopen402.settings import CiA402Settings
from drivers.canopen402.supervision import check_drives, named_step
from drivers.canopen402.tables import Controlword, DriveState
from drivers.canopen402.targets import Targets
from drivers.canopen402.watchdog import DriveWatchdog
from drivers.device_thread import DeviceThread
from drivers.readiness import Finding

T = TypeVar("T")

FIRST_CYCLE_TIMEOUT_S = 1.0


class CiA402Driver(Driver):
    settings_type = CiA402Settings
    capabilities = frozenset({CommandKind.POSITION, CommandKind.HOLD, CommandKind.STOP})
    """Cyclic synchronous position only: no VELOCITY (CSV) and no IMPEDANCE (CST with a
    compliance law warden does not run), so compliant targets go out as positions."""
    address_keys: ClassVar[Mapping[str, str]] = settings_module.ADDRESS_KEYS
    default_name = "canopen402"
    device_watchdog = staticmethod(settings_module.device_watchdog)
    """What stops the arm when warden's commands stop, per manifest table (None: off)."""
    device_identity = staticmethod(settings_module.device_identity)
    """The device a manifest table addresses (one warden per device: kernel/shell/device_lock)."""
    device_watchdog_ms = staticmethod(settings_module.device_watchdog_ms)
    """...and how long after warden's last command it does, in ms."""

    def __init__(self, settings: CiA402Settings) -> None:
        self.settings = settings
        self.name = settings.name
        self._scales = settings.joint_scales()
        self._health = HealthMonitor(settings)
        self._thread: DeviceThread | None = None
        self._link: Link | None = None
        self._cycle: BusCycle | None = None
        self._control: ControlConfig | None = None
        self._rated_torque: tuple[int, ...] = ()
        self._targets = Targets(self._scales)
        self._gripper: Gripper | None = None
        self._active = False
        self._powered = False
        """Some drive may be enabled: set before an enable starts, so a half-done activate
        is still quick-stopped on close."""
        self._stop_requested = False
        self._commanded = False
        """A command reached the drives since activation (deactivate then holds them)."""
        self._closed = False
        self._seq = 0
        self._watchdog = DriveWatchdog(settings)

    @classmethod
    def from_settings(cls, settings: CiA402Settings, name: str | None = None) -> CiA402Driver:
        """The drives' errors name them by ``settings.name``: ``name`` replaces it."""
        return cls(settings if name is None else msgspec.structs.replace(settings, name=name))

    @property
    def cycle(self) -> BusCycle | None:
        """The bus cycle (SYNC count, round-trip latencies); None before configure."""
        return self._cycle

    @property
    def link(self) -> Link | None:
        """The open bus, canopen network and nodes, for diagnostics; None when closed."""
        return self._link

    # -- lifecycle hooks -----------------------------------------------------------------------

    async def connect(self) -> None:
        if self._link is not None or self._closed:
            raise DriverInitError(self.name, "connect needs a fresh driver object")
        self._thread = DeviceThread(self.name)
        try:
            self._link = await self._blocking("open the CAN bus", build_link, self.settings)
            self._watchdog.attach(self._link.network)
            for node in self._link.nodes:
                self._health.attach(node)
            self._link.start_notifier(asyncio.get_running_loop())
            await self._blocking("bring-up", bringup.bring_up, self._nodes(), self.settings,
                                 self._health)
        except BaseException:
            await self.aclose()
            raise

    async def configure(self, control: ControlConfig) -> None:
        joints = self._require_link().joints
        if control.dof != len(joints):
            raise DriverInitError(self.name, f"the control loop has {control.dof} joints but "
                                  f"node_ids lists {len(joints)} drives")
        bringup.check_bus_load(self.settings, control.period_ns * 1e-9)
        try:
            self.settings.check_watchdog(control.period_ns * 1e-9)
        except ValueError as error:
            raise DriverInitError(self.name, str(error)) from error
        self._control = control
        self._targets.readings.configure(control)
        self._rated_torque = await self._blocking(
            "PDO and parameter setup", parameters.configure_drives, self._require_link(),
            self.settings, self._scales, control)
        self._start_cycle(control)
        await self._blocking("NMT start", bringup.enter_operational, self._nodes(),
                             self.settings, self._health)
        await self._await_cycle("the first TPDOs after NMT start")
        await self._blocking("CSP mode and SWITCH ON DISABLED", bringup.settle, self._nodes(),
                             self.settings)
        self._check()

    def _start_cycle(self, control: ControlConfig) -> None:
        link = self._require_link()
        self._targets.bind(link.joints)
        if link.gripper is not None:
            self._gripper = Gripper(link.gripper, self.settings.gripper_scale())
        self._cycle = start_bus_cycle(link, control.period_ns * 1e-9, self._health.on_tpdo)

    async def activate(self) -> None:
        self._check()
        self._hold_here()  # a CSP drive follows its target at once: start from where it is
        if self._gripper is not None:
            self._gripper.start_here()
        self._stop_requested = self._commanded = False
        self._powered = True
        await self._blocking("enable", self._for_each, walk_to, DriveState.OPERATION_ENABLED,
                             self.settings)
        self._active = True
        self._check()

    async def read(self) -> StateSample:
        self._check()
        return self._sample()

    async def next_sample(self, timeout_s: float = 1.0) -> StateSample:
        """The sample answering the most recent SYNC: waits until all its TPDOs are in."""
        await self._await_cycle("the TPDOs of the last SYNC", timeout_s)
        return await self.read()

    async def before_first_tick(self) -> None:
        """Arm the drives' watchdog now, right before the loop's first tick: armed by the
        first setpoint, its SDO round trips (one per drive) stalled that tick 0.2-0.9 s on a
        loaded host, past the state watchdog, a CONTROLLER_STOP before any motion."""
        self._check()
        await self._arm_watchdog()

    async def write(self, command: Command) -> Applied:
        self._check()
        self._commanded = True
        if command.kind is CommandKind.POSITION:
            await self._arm_watchdog()  # a loop without before_first_tick: see watchdog.py
        self._watchdog.beat()
        if command.kind is CommandKind.POSITION:
            return await self._write_position(command)
        if command.kind is CommandKind.HOLD:
            return await self.hold()
        if command.kind is CommandKind.STOP:
            return self._quick_stop()
        return self._refuse(command.kind, ReasonCode.CONTROLLER_MODE_MISMATCH)

    async def hold(self) -> Applied:
        self._check()
        self._commanded = True
        self._watchdog.beat()
        q = self._held_targets()
        self._keep_gripper()
        await self._leave_quick_stop()
        if self._active:
            self._tick()
        return Applied(kind=CommandKind.HOLD, t_mono_ns=time.monotonic_ns(), q=q)

    async def deactivate(self) -> None:
        self._active = False
        if self._commanded:  # else the targets set at activation hold: rewriting is motion
            self._held_targets()
            self._keep_gripper()
        if self._watchdog.armed:  # beating meanwhile (_blocking): no drive stops on the way
            await self._blocking("disarm the drives' watchdog", self._for_each, watchdog.disarm)
            self._watchdog.armed = False
        await self._blocking("disable", self._for_each, self._disable_unless_faulted)
        self._powered = self._stop_requested = False
        self._check()

    def _disable_unless_faulted(self, node: Node402) -> None:
        # A faulted drive stays as it is: walking it anywhere would mean resetting the fault.
        if current_state(node) not in FAULTY:
            walk_to(node, DriveState.SWITCH_ON_DISABLED, self.settings)

    async def aclose(self) -> None:
        """Quick-stop enabled drives, stop the cycle, NMT pre-operational, release the bus."""
        if self._closed:
            return
        self._closed = True
        try:
            self._quick_stop_on_close()
        finally:
            if self._cycle is not None:
                self._cycle.stop()
            await self._close_link()
            if self._thread is not None:
                self._thread.close()

    # -- the cyclic path -----------------------------------------------------------------------

    async def _arm_watchdog(self) -> None:
        if self._watchdog.to_arm:
            await self._blocking("arm the drives' watchdog", self._for_each, watchdog.arm,
                                 self._watchdog.entry)
            self._watchdog.armed = True

    async def _write_position(self, command: Command) -> Applied:
        control = self._require_control()
        if len(command.q) != control.dof:
            return self._refuse(command.kind, ReasonCode.MALFORMED)
        if not (all(math.isfinite(v) for v in command.q) and gripper.valid_opening(
                command.gripper)):
            return self._refuse(command.kind, ReasonCode.NONFINITE)
        if self._stop_requested:  # the core resumes (an operator accepted recovery)
            self._held_targets()
            self._keep_gripper()
            await self._leave_quick_stop()
        applied = self._targets.command(command.q, control)
        if self._gripper is not None:
            self._gripper.command(command.gripper)
        self._tick()
        return Applied(kind=CommandKind.POSITION, t_mono_ns=time.monotonic_ns(), q=applied)

    def _quick_stop(self) -> Applied:
        for node in self._require_link().joints:
            node.controlword = Controlword.QUICK_STOP
        self._keep_gripper()  # stays enabled, see Gripper.keep
        self._stop_requested = True
        self._tick()
        return Applied(kind=CommandKind.STOP, t_mono_ns=time.monotonic_ns(),
                       q=self._sample().q)

    async def _leave_quick_stop(self) -> None:
        """QUICK STOP ACTIVE → OPERATION ENABLED (transition 16), after our own quick stop.

        The targets must already be where the stop left the drives (:meth:`_held_targets`):
        an enabled CSP drive follows its target at once, and the one it had before the stop
        is where the ramp did not take it."""
        if not (self._active and self._stop_requested):
            return
        await self._blocking("re-enable after quick stop", self._for_each, walk_to,
                             DriveState.OPERATION_ENABLED, self.settings)
        self._stop_requested = False

    def _held_targets(self) -> tuple[float, ...]:
        """The targets a hold keeps, in radians: as they are, unless a quick stop moved the
        drives away from them (then where the stop left them, :meth:`_hold_here`)."""
        return self._hold_here() if self._stop_requested else self._targets.kept()

    def _hold_here(self) -> tuple[float, ...]:
        return self._targets.here(self._require_link().joints, self._rated_torque)

    def _keep_gripper(self) -> None:
        if self._gripper is not None:
            self._gripper.keep()

    def _tick(self) -> None:
        try:
            self._require_cycle().tick(from_write=True)
        except can.CanError as error:
            raise DriverIOError(self.name, f"sending on {self.settings.describe_bus()} failed: "
                                f"{error}") from error

    def _sample(self) -> StateSample:
        q, qd, effort = joint_readings(self._require_link().joints, self._scales,
                                       self._rated_torque)
        self._targets.readings.judge(time.monotonic_ns(), q, qd)
        self._seq += 1
        opening = self._gripper.opening() if self._gripper is not None else None
        return StateSample(seq=self._seq, t_mono_ns=time.monotonic_ns(), source=self.name,
                           q=q, qd=qd, effort=effort, gripper=opening)

    def _refuse(self, kind: CommandKind, reason: ReasonCode) -> Applied:
        return Applied(kind=kind, t_mono_ns=time.monotonic_ns(), accepted=False, reason=reason)

    # -- checks --------------------------------------------------------------------------------

    async def inspect(self) -> tuple[Finding, ...] | None:
        """Each drive's objects against the settings and limits (reads only; ``warden check``,
        see :mod:`drivers.canopen402.inspection`)."""
        self._check()
        drives = await self._blocking("inspect the drives", inspection.read_configuration,
                                      self._nodes())
        opening = self._gripper.opening() if self._gripper is not None else None
        return inspection.findings(inspection.Inspected(self.settings, self._require_control(),
                                                        drives, opening))

    def drive_states(self) -> dict[int, DriveState]:
        """Each node's 402 state from its last statusword."""
        return {node.id: current_state(node) for node in self._nodes()}

    def _check(self) -> None:
        """Raise what the drives reported since the last call (EMCY, silence, state)."""
        check_drives(self._health, self._require_link(), self._cycle, self.settings,
                     self._active, self._stop_requested)

    # -- plumbing ------------------------------------------------------------------------------

    async def _blocking(self, label: str, fn: Callable[..., T], *args: object) -> T:
        """Run a blocking step on the device thread, naming the step in any error."""
        if self._thread is None:
            raise NotConnected(self.name, f"{label}: not connected")
        with named_step(self.name, label):
            async with self._watchdog.kept_up():
                return await self._thread.run(self.settings.call_timeout_s, fn, *args)

    def _for_each(self, step: Callable[..., None], *args: object) -> None:
        for node in self._nodes():
            step(node, *args)

    async def _await_cycle(self, what: str, timeout_s: float = FIRST_CYCLE_TIMEOUT_S) -> None:
        cycle = self._require_cycle()
        if not await cycle.wait_completed(cycle.cycle, timeout_s):
            raise DriverTimeout(self.name, f"{what} did not all arrive within {timeout_s} s")

    def _quick_stop_on_close(self) -> None:
        if not (self._powered and self._cycle is not None and self._link is not None):
            return
        self._active = self._powered = False
        self._link.quick_stop(self._cycle.tick)  # the gripper too: closing ends every motion

    async def _close_link(self) -> None:
        link, self._link = self._link, None
        if link is not None:
            await link.aclose()

    def _nodes(self) -> tuple[Node402, ...]:
        return self._require_link().nodes

    def _require_link(self) -> Link:
        if self._link is None:
            raise NotConnected(self.name, "not connected" if not self._closed else "closed")
        return self._link

    def _require_cycle(self) -> BusCycle:
        if self._cycle is None:
            raise NotConnected(self.name, "not configured: no bus cycle yet")
        return self._cycle

    def _require_control(self) -> ControlConfig:
        if self._control is None:
            raise NotConnected(self.name, "not configured")
        return self._control
