"""Universal Robots e-Series over RTDE, through the real ur_rtde 1.6.5 library.

Positions stream as servoJ at the control rate, velocities as speedJ; STOP is stopJ (once: STOP
repeated while the arm stays stopped only kicks the watchdog), HOLD is
servoJ to the last position this driver commanded (the measured one only when there is none:
after activation, a velocity or a stop, and only a plausible one, ``drivers.plausible``; stopJ
while inactive). Every read takes one snapshot of the
receive interface and maps the controller's own words: safety bits (e-stop → E_STOP,
protective/safeguard stop → CONTROLLER_FAULT), robot mode and runtime state while streaming
(→ CONTROLLER_FAULT), a timestamp that stopped advancing (→ WATCHDOG) and a lost link
(→ LINK_LOST). All library calls run on this device's thread with a deadline; see ``_sdk``
for why construction, destruction and blocking commands are handled with such care.

The controller-side RTDE watchdog (``watchdog_periods``, see ``watchdog``) stops the arm when
warden dies or hangs: the first motion setpoint after activation arms it (the kernel's bring-up
sends nothing for longer than a watchdog between activation and its first tick, and an arm that
was never given a setpoint has nothing to stop), every setpoint feeds it, a write cycle that
sends none kicks it, deactivate removes it. A control script that stops while it is armed is
reported as WATCHDOG.

With ``gripper_output`` set, a binary two-finger gripper on a tool digital output follows
``Command.gripper`` of POSITION and VELOCITY commands (see ``gripper``): its output is written
through ur_rtde's IO interface only when the commanded state changes, HOLD and STOP leave it as
it is, and every read reports the measured opening as ``StateSample.gripper``.

``inspect`` (``warden check``) compares what the controller reports with what a run needs of it,
reading only (:mod:`drivers.ur_rtde.inspection`).
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable, Mapping
from typing import ClassVar, TypeVar

from assurance.reasons import ReasonCode
from drivers.base import (
    Applied,
    Command,
    CommandKind,
    ControlConfig,
    DeviceFault,
    Driver,
    DriverError,
    DriverInitError,
    DriverIOError,
    DriverTimeout,
    NotConnected,
    StateSample,
)
from drivers.device_thread import DeviceThread
from drivers.plausible import LastPlausible
from drivers.readiness import Finding
from drivers.ur_rtde import inspection, setpoints, tables
from drivers.ur_rtde import settings as settings_module
from drivers.ur_rtde.link import Link, LinkDown, LinkStalled, Mode, Snapshot
from drivers.ur_rtde.probe import ControllerUnreachable, probe_controller
from drivers.ur_rtde.settings import URSettings
from drivers.ur_rtde.stopping import BackgroundStop

T = TypeVar("T")
CLOSE_TIMEOUT_S = 10.0
"""aclose waits this long: ur_rtde's disconnect can sit out its own 2.5 s read deadline."""


class URRTDEDriver(Driver):
    """One UR arm. ``settings`` come from the manifest; ``name`` labels errors and traces."""

    settings_type = URSettings
    capabilities = frozenset({CommandKind.POSITION, CommandKind.VELOCITY, CommandKind.HOLD,
                              CommandKind.STOP})
    """No IMPEDANCE: servoJ and speedJ only (the controller's force mode is not joint-space
    impedance), so compliant targets go out as positions."""
    address_keys: ClassVar[Mapping[str, str]] = settings_module.ADDRESS_KEYS
    default_name = "ur_rtde"
    device_watchdog = staticmethod(settings_module.device_watchdog)
    """What stops the arm when warden's commands stop, per manifest table (None: off)."""
    device_identity = staticmethod(settings_module.device_identity)
    """The device a manifest table addresses (one warden per device: kernel/shell/device_lock)."""
    device_watchdog_ms = staticmethod(settings_module.device_watchdog_ms)
    """...and how long after warden's last command it does, in ms."""

    def __init__(self, settings: URSettings, name: str = "ur_rtde") -> None:
        self.name = name
        self.settings = settings
        self._thread: DeviceThread | None = None
        self._link: Link | None = None
        self._control: ControlConfig | None = None
        self._watchdog_hz: float | None = None
        self._version: tuple[int, ...] = ()
        """URControl's version as the pre-flight probe read it."""
        self._active = False
        self._seq = 0
        self._stop_call = BackgroundStop(self._driver_error)
        self._last: StateSample | None = None
        self._commanded: tuple[float, ...] | None = None
        """The position the arm was last servoed to since activation (setpoint or hold), where
        a HOLD holds: a reading may be glitched, and servoing to it would move the arm there.
        None after a velocity or a stop (the arm ended somewhere no setpoint said)."""
        self._readings = LastPlausible()
        """Every reading, judged as the core judges its samples: with nothing commanded (after
        a stop) a hold holds at a plausible one only."""

    @property
    def controller_time_s(self) -> float | None:
        """The controller's own clock in the newest sample read (diagnostics, benchmarks)."""
        if self._link is None or self._link.last_timestamp < 0:
            return None
        return self._link.last_timestamp

    # -- lifecycle hooks ----------------------------------------------------------------------

    async def connect(self) -> None:
        """Pre-flight the controller, then open both interfaces, in a bounded number of tries."""
        if self._thread is None:
            self._thread = DeviceThread(self.name)
        attempts = 1 + self.settings.reconnect_attempts
        for attempt in range(1, attempts + 1):
            try:
                await self._connect_once()
                return
            except ControllerUnreachable:
                if attempt == attempts:
                    raise
                await asyncio.sleep(self.settings.reconnect_backoff_s)

    async def configure(self, control: ControlConfig) -> None:
        host = self.settings.host
        sizes = {control.dof, len(control.q_lower), len(control.q_upper), len(control.v_max)}
        if sizes != {tables.DOF}:
            raise DriverInitError(self.name, f"the UR arm at {host} has {tables.DOF} joints; "
                                  f"the manifest's control loop and limits say {control.dof} "
                                  f"(limits of {len(control.q_lower)}, {len(control.q_upper)}, "
                                  f"{len(control.v_max)})")
        if control.period_ns * 1e-9 < self.settings.rtde_period_s:
            raise DriverInitError(
                self.name, f"control period {control.period_ns / 1e6:.3f} ms is shorter than "
                f"the RTDE period of the arm at {host} ({self.settings.frequency_hz} Hz): "
                "raise frequency_hz or lower the control rate")
        self._control = control
        self._readings.configure(control)
        self._watchdog_hz = self.settings.watchdog_frequency_hz(control.period_ns * 1e-9)

    async def activate(self) -> None:
        """Check the arm can follow setpoints; restart the control script if it had stopped."""
        await self._read_checked(streaming=False)
        link = self._link_or_raise()
        if not await self._run(link.program_running):
            await self._run(link.restart_script, timeout_s=self.settings.stop_timeout_s)
        await self._read_checked(streaming=True)
        self._active, self._stop_call.stopped, self._commanded = True, False, None

    async def before_first_tick(self) -> None:
        """Arm the controller's watchdog now, right before the loop's first tick, so that its
        round trip is not a stall of the loop (the first setpoint follows within a period)."""
        link = self._link_or_raise()
        if self._watchdog_hz is not None and not link.watchdog.armed:
            await self._arm_watchdog(link, self._watchdog_hz)

    async def read(self) -> StateSample:
        if self._stop_call.under_way() and self._last is not None:
            return self._last  # the device thread is busy stopping the arm: no new sample
        snapshot = await self._read_checked(streaming=self._active)
        self._readings.judge(snapshot.t_mono_ns, snapshot.q, snapshot.qd)
        self._seq += 1
        self._last = StateSample(
            seq=self._seq, t_mono_ns=snapshot.t_mono_ns, source=self.name, q=snapshot.q,
            qd=snapshot.qd, wrench=snapshot.tcp_force, speed_scaling=snapshot.speed_scaling,
            gripper=snapshot.gripper_opening,
        )
        return self._last

    async def write(self, command: Command) -> Applied:
        if command.kind is CommandKind.STOP:
            return await self._stop()
        await self._stop_call.finished()
        moves = command.kind in (CommandKind.POSITION, CommandKind.VELOCITY)
        if moves and command.gripper is not None and not math.isfinite(command.gripper):
            return await self._refused_and_kicked(command.kind)
        applied = await self._move(command)
        if moves and applied.accepted:  # HOLD and STOP leave the gripper as it is
            await self._grip(command.gripper)
        return applied

    async def _move(self, command: Command) -> Applied:
        link = self._link_or_raise()
        if command.kind is not CommandKind.STOP:
            self._stop_call.stopped = False
        if command.kind is CommandKind.POSITION:
            if not setpoints.well_formed(command.q):
                return await self._refused_and_kicked(command.kind)
            if self._watchdog_hz is not None and not link.watchdog.armed:
                await self._arm_watchdog(link, self._watchdog_hz)
            q = setpoints.clip_position(self._control, command.q)
            return await self._servo(command.kind, link, q)
        if command.kind is CommandKind.VELOCITY:
            if not setpoints.well_formed(command.qd):
                return await self._refused_and_kicked(command.kind)
            if self._watchdog_hz is not None and not link.watchdog.armed:
                await self._arm_watchdog(link, self._watchdog_hz)
            qd = setpoints.clip_velocity(self._control, command.qd)
            self._commanded = None
            return await self._applied(command.kind, lambda: link.speed_j(qd), qd=qd,
                                       timeout_s=self._setpoint_timeout(link, Mode.SPEED))
        if command.kind is CommandKind.HOLD:
            return await self.hold()
        if command.kind is CommandKind.STOP:
            return await self._stop()
        # Not one of ``capabilities`` (IMPEDANCE): the lifecycle never sends it; this one
        # came around it, and used to become a stop.
        return await self._refused_and_kicked(command.kind, ReasonCode.CONTROLLER_MODE_MISMATCH)

    async def hold(self) -> Applied:
        """Servo to the last commanded position while streaming (the measured one if none,
        after activation or a stop, and only if plausible: else the last plausible reading);
        stopJ when not streaming.

        Never to a fresh reading once a position was commanded: a glitched one (an encoder
        or frame reporting a joint 0.5 rad off) held every tick of an operator's takeover
        moved the arm 0.5 rad toward it, and chased the glitch for as long as it lasted."""
        await self._stop_call.finished()
        link = self._link_or_raise()
        self._stop_call.stopped = False
        snapshot = await self._read_checked(streaming=self._active)  # and its status words
        measured = self._readings.believed(snapshot.t_mono_ns, snapshot.q, snapshot.qd)
        measured = measured or snapshot.q
        if self._active:
            q = self._commanded if self._commanded is not None else measured
            return await self._servo(CommandKind.HOLD, link, q)
        await self._run(link.stop, timeout_s=self.settings.stop_timeout_s)
        return Applied(kind=CommandKind.HOLD, t_mono_ns=time.monotonic_ns(), q=measured)

    async def _servo(self, kind: CommandKind, link: Link, q: tuple[float, ...]) -> Applied:
        """servoJ to ``q``, remembered as where a hold holds once the controller took it."""
        dt = max(self._period_s(), tables.CONTROLLER_CYCLE_S)
        applied = await self._applied(kind, lambda: link.servo_j(q, dt), q=q,
                                      timeout_s=self._setpoint_timeout(link, Mode.SERVO))
        if applied.accepted:
            self._commanded = q
        return applied

    async def deactivate(self) -> None:
        """End servo or speed mode (the arm decelerates and stays powered), then remove the
        watchdog: that stops the control script; the next activation uploads it again."""
        await self._stop_call.finished()
        self._active = self._stop_call.stopped = False
        self._commanded = None
        link = self._link_or_raise()
        await self._run(link.end_streaming, timeout_s=self.settings.stop_timeout_s)
        await self._run(link.disarm_watchdog, timeout_s=self.settings.stop_timeout_s)

    async def inspect(self) -> tuple[Finding, ...] | None:
        """The controller's status words and speed factors against what a run needs (reads)."""
        status = await self._run(inspection.read_status, self._link_or_raise())
        return inspection.findings(self.settings, self._version, status, self._watchdog_hz)

    async def aclose(self) -> None:
        """Stop the script if the link is healthy, release both interfaces. Safe to call twice."""
        self._active = False
        thread, link = self._thread, self._link
        self._thread, self._link, self._stop_call.call = None, None, None
        if thread is None:
            return
        try:
            if link is not None:
                await thread.run(CLOSE_TIMEOUT_S, link.release)
        except DriverTimeout:
            pass  # the device thread is abandoned inside the library; nothing else holds it
        finally:
            thread.close()

    # -- helpers ------------------------------------------------------------------------------

    async def _connect_once(self) -> None:
        settings = self.settings
        # The probe makes four connections, each bounded by connect_timeout_s.
        version = await self._run(probe_controller, self.name, settings.host,
                                  settings.connect_timeout_s,
                                  timeout_s=5 * settings.connect_timeout_s)
        if not tables.version_supported(version):
            raise DriverInitError(
                self.name, f"the controller at {settings.host} reports URControl "
                f"{'.'.join(map(str, version))}; this driver needs e-Series PolyScope "
                f"{'.'.join(map(str, tables.MIN_VERSION))} or newer 5.x: check the controller "
                "software (CB3 and PolyScope X speak a different protocol to this driver)")
        self._version = version
        if self._link is None:
            self._link = Link(self.name, settings)
        await self._run(self._link.open, timeout_s=2 * settings.connect_timeout_s)

    async def _grip(self, opening: float | None) -> None:
        """Switch the gripper when the commanded state changes, or when the controller's
        readback does not confirm it: one IO package per change, so a held command costs
        nothing per tick, yet a write the IO session lost without an error is sent again."""
        link = self._link_or_raise()
        if opening is None or link.gripper is None:
            return
        closed = link.gripper.closes(opening)
        if link.gripper_needs_write(closed):
            await self._run(link.set_gripper, closed)

    async def _arm_watchdog(self, link: Link, frequency_hz: float) -> None:
        """Once per activation, with the first motion setpoint (one blocking round trip)."""
        if not await self._run(link.arm_watchdog, frequency_hz,
                               timeout_s=self.settings.stop_timeout_s):
            await self._read_checked(streaming=True)  # the status words say why, if they can
            raise DeviceFault(self.name, f"the control script on the arm at "
                              f"{self.settings.host} did not confirm setWatchdog("
                              f"{frequency_hz:g} Hz)", ReasonCode.CONTROLLER_REJECT)

    async def _refused_and_kicked(self, kind: CommandKind,
                                  reason: ReasonCode = ReasonCode.NONFINITE) -> Applied:
        """A setpoint refused before it reached the library: nothing went out, so kick the
        watchdog (warden is alive; what to do about bad setpoints is the kernel's call)."""
        await self._run(self._link_or_raise().kick_watchdog)
        return setpoints.refused(kind, reason)

    async def _read_checked(self, streaming: bool) -> Snapshot:
        link = self._link_or_raise()
        snapshot = await self._run(link.snapshot)
        faults = tables.device_faults(snapshot.safety_bits, snapshot.robot_mode,
                                      snapshot.runtime_state, streaming, link.watchdog.timeout_s)
        if faults:
            detail = "; ".join(fault.detail for fault in faults)
            raise DeviceFault(self.name, f"arm at {self.settings.host}: {detail}",
                              faults[0].reason)
        return snapshot

    async def _applied(self, kind: CommandKind, send: Callable[[], bool], *,
                       q: tuple[float, ...] = (), qd: tuple[float, ...] = (),
                       timeout_s: float | None = None) -> Applied:
        if await self._run(send, timeout_s=timeout_s):
            return Applied(kind=kind, t_mono_ns=time.monotonic_ns(), q=q, qd=qd)
        # The library says no without saying why: the status words do.
        await self._read_checked(streaming=True)
        return setpoints.refused(kind, ReasonCode.CONTROLLER_REJECT)

    async def _stop(self) -> Applied:
        """Stop once, without the loop waiting for it (:mod:`drivers.ur_rtde.stopping`); a
        STOP repeated while the arm stays stopped (every tick of E_STOP and CONTROLLER_STOP)
        only reads the status words and kicks the watchdog."""
        link = self._link_or_raise()
        if self._stop_call.under_way():
            return self._stop_applied()
        if self._stop_call.stopped and link.mode is Mode.IDLE:
            q = (await self._read_checked(streaming=False)).q
            await self._run(link.kick_watchdog)
            return Applied(kind=CommandKind.STOP, t_mono_ns=time.monotonic_ns(), q=q)
        if self._thread is None:
            raise NotConnected(self.name, f"not connected to the arm at {self.settings.host}")
        self._commanded = None
        self._stop_call.start(self._thread, self.settings.stop_timeout_s, link.stop)
        return self._stop_applied()

    def _stop_applied(self) -> Applied:
        q = self._last.q if self._last is not None else ()
        return Applied(kind=CommandKind.STOP, t_mono_ns=time.monotonic_ns(), q=q)

    async def _run(self, fn: Callable[..., T], *args: object, timeout_s: float | None = None
                   ) -> T:
        """Call ``fn`` on the device thread; turn link trouble into the driver's errors."""
        if self._thread is None:
            raise NotConnected(self.name, f"not connected to the arm at {self.settings.host}")
        try:
            return await self._thread.run(timeout_s or self.settings.call_timeout_s, fn, *args)
        except (LinkDown, LinkStalled, RuntimeError) as error:
            raise self._driver_error(error) from error

    def _driver_error(self, error: BaseException) -> BaseException:
        """The driver's error for link trouble; anything else as it is."""
        if isinstance(error, LinkDown):
            return NotConnected(self.name, f"{self.settings.host}: {error}")
        if isinstance(error, LinkStalled):
            return DriverTimeout(self.name, f"{self.settings.host}: {error}")
        if isinstance(error, RuntimeError) and not isinstance(error, DriverError):
            return DriverIOError(self.name, f"ur_rtde: {error}")
        return error

    def _link_or_raise(self) -> Link:
        if self._link is None:
            raise NotConnected(self.name, f"not connected to the arm at {self.settings.host}")
        return self._link

    def _setpoint_timeout(self, link: Link, mode: Mode) -> float:
        # Changing between servo and speed mode first stops the other one, and that waits
        # for the arm to decelerate.
        if link.switching_to(mode):
            return self.settings.stop_timeout_s
        return self.settings.call_timeout_s

    def _period_s(self) -> float:
        return self._control.period_ns * 1e-9 if self._control else tables.CONTROLLER_CYCLE_S
