"""Everything that touches ur_rtde objects. Runs only on the device thread, one call at a time.

The link owns the receive and control interfaces (and the IO interface when the arm has a
gripper), the streaming mode (servo, speed or none), the control script's RTDE watchdog
(:mod:`drivers.ur_rtde.watchdog`) and the freshness of the data stream.
Blocking commands are sent only after the stream proved fresh: on a dead or stalled link
ur_rtde would wait up to 300 s for a "done" that never comes, and a thread stuck there cannot
even be joined at exit.
"""

from __future__ import annotations

import contextlib
import ctypes
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

from assurance.reasons import ReasonCode
from drivers.base import DeviceFault, DriverInitError
from drivers.ur_rtde import _sdk, tables
from drivers.ur_rtde.gripper import GripperWiring
from drivers.ur_rtde.settings import URSettings
from drivers.ur_rtde.watchdog import ControlWatchdog

SCRIPT_START_TIMEOUT_S = 1.0
POLL_S = 0.0005
IO_RENEW_ATTEMPTS, IO_RENEW_BACKOFF_S = 3, 0.05
GRIPPER_CONFIRM_S = 0.1
"""How long a written gripper output may take to show in actual_digital_output_bits."""


class LinkDown(ConnectionError):
    """An interface reports it is no longer connected (→ NotConnected, LINK_LOST)."""


class LinkStalled(Exception):
    """The controller stopped sending new data (→ DriverTimeout, WATCHDOG).

    Deliberately not a TimeoutError: DeviceThread.run reads any TimeoutError that leaves the
    call as its own deadline expiring, and would report "took longer than" instead of this."""


class Mode(StrEnum):
    IDLE = "idle"
    SERVO = "servo"
    SPEED = "speed"


@dataclass(frozen=True, slots=True)
class Snapshot:
    t_mono_ns: int
    timestamp: float
    q: tuple[float, ...]
    qd: tuple[float, ...]
    tcp_force: tuple[float, ...]
    robot_mode: int
    safety_bits: int
    runtime_state: int
    speed_scaling: float
    """Effective scaling: the trajectory limiter's speed_scaling times the speed slider."""
    gripper_opening: float | None = None
    """The gripper's opening (m) from its feedback input (None: no gripper)."""


class Link:
    def __init__(self, device: str, settings: URSettings) -> None:
        self.device = device
        self.settings = settings
        self.receive: _sdk.ReceiveInterface | None = None
        self.control: _sdk.ControlInterface | None = None
        self.io: _sdk.IOInterface | None = None
        self.gripper = GripperWiring.from_settings(settings)
        self.gripper_closed: bool | None = None
        """The gripper output level last written (True = closed); None: not known."""
        self.gripper_output_high: bool | None = None
        """That output as the controller reports it, from the newest snapshot."""
        self._gripper_written_ns = self._gripper_read_ns = 0
        self.mode = Mode.IDLE
        self.watchdog = ControlWatchdog(device, settings.host, settings.stop_timeout_s)
        self._last_timestamp = -1.0
        self._last_change_ns = 0

    # -- connection ---------------------------------------------------------------------------

    def open(self) -> None:
        """Open the receive session, check the arm, then the control session.

        An interface that lost its link is ``reconnect()``-ed (our bounded retry, called only
        from connect): unlike building a new one, that neither leaks the old one nor runs its
        destructor, which sleeps 0.5 s with the GIL held.
        """
        host = self.settings.host
        try:
            self._open_receive()
            self._check_ready_for_script()
            self._open_control()
            self._open_io()
        except RuntimeError as error:  # ur_rtde reports every connection problem this way
            raise DriverInitError(self.device, f"ur_rtde could not connect to the arm at {host}: "
                                  f"{error}") from error
        self.mode = Mode.IDLE
        self.watchdog.forget()  # constructing or reconnecting the control interface uploads
        # the script afresh (stopping one that ran): no watchdog yet
        self.gripper_closed = None  # whatever was written before, the controller may differ
        self.gripper_output_high = None
        self._last_change_ns = time.monotonic_ns()

    def _open_receive(self) -> None:
        if self.receive is None:
            feedback = [self.gripper.feedback, "actual_digital_output_bits"] if (
                self.gripper) else []
            self.receive = _sdk.open_receive(self.settings.host, self.settings.frequency_hz,
                                             tables.RECEIVE_VARIABLES + feedback)
        elif not self.receive.isConnected():
            self.receive.reconnect()

    def _open_control(self) -> None:
        if self.control is None:
            self.control = _sdk.open_control(self.settings.host)
        elif not self.control.isConnected():
            self.control.reconnect()

    def _open_io(self) -> None:
        if self.gripper is None:
            return
        if self.io is None:
            self.io = _sdk.open_io(self.settings.host)
        else:  # renewed every time: its isConnected() cannot tell if the controller dropped it
            self._renew_io(self.io)

    @staticmethod
    def _renew_io(io: _sdk.IOInterface) -> None:
        # A dropped session raises here: the "pause" it sends on disconnect finds no session.
        with contextlib.suppress(RuntimeError):
            io.disconnect()
        for attempt in range(1, IO_RENEW_ATTEMPTS + 1):
            try:
                io.reconnect()
                return
            except RuntimeError:
                # The controller frees the old session's registers once it sees that session
                # close, which can come after the new one asks for them (IN_USE): wait a bit.
                if attempt == IO_RENEW_ATTEMPTS:
                    raise
                time.sleep(IO_RENEW_BACKOFF_S)

    def _check_ready_for_script(self) -> None:
        # The control constructor waits 5 s (GIL held) for a script the controller will not
        # start during a safety stop or without power: find out first, and say why.
        receive = self._receive()
        bits, robot_mode = receive.getSafetyStatusBits(), receive.getRobotMode()
        faults = tables.device_faults(bits, robot_mode, tables.RuntimeState.PLAYING, True)
        if faults:
            raise DeviceFault(self.device, f"arm at {self.settings.host} cannot run the control "
                              f"script: {faults[0].detail}", faults[0].reason)

    def release(self) -> None:
        """Stop the control script if healthy; drop the interfaces (their destructors sleep)."""
        healthy = self._fresh()
        control, receive, io = self.control, self.receive, self.io
        self.control, self.receive, self.io = None, None, None
        self.watchdog.forget()  # stopScript below ends the script, a lost link ended it already
        if io is not None:  # first: its disconnect waits for an answer, and "healthy" is now
            release_io(io, healthy)
        if control is not None:
            _close(control, healthy, control.stopScript)
            del control  # destructor runs here, on the device thread, not on the event loop
        if receive is not None:
            _close(receive, healthy, lambda: None)
            del receive

    # -- reading ------------------------------------------------------------------------------

    def snapshot(self) -> Snapshot:
        receive = self._require_connected()
        now = time.monotonic_ns()
        snapshot = Snapshot(
            t_mono_ns=now, timestamp=receive.getTimestamp(), q=tuple(receive.getActualQ()),
            qd=tuple(receive.getActualQd()), tcp_force=tuple(receive.getActualTCPForce()),
            robot_mode=receive.getRobotMode(), safety_bits=receive.getSafetyStatusBits(),
            runtime_state=receive.getRuntimeState(),
            speed_scaling=receive.getSpeedScaling() * receive.getTargetSpeedFraction(),
            gripper_opening=self.gripper.opening_m(getattr(receive, self.gripper.getter)())
            if self.gripper else None,
        )
        self._track_freshness(snapshot.timestamp, now)
        if self.gripper is not None:
            self.gripper_output_high = self.gripper.output_high(
                receive.getActualDigitalOutputBits())
            self._gripper_read_ns = now
        return snapshot

    @property
    def last_timestamp(self) -> float:
        """The controller's clock (s since it booted) in the newest sample read, or -1."""
        return self._last_timestamp

    def _track_freshness(self, timestamp: float, now_ns: int) -> None:
        if timestamp != self._last_timestamp:
            self._last_timestamp, self._last_change_ns = timestamp, now_ns
            return
        age_s = (now_ns - self._last_change_ns) * 1e-9
        if age_s > self.settings.stall_after_s:
            raise LinkStalled(f"no new RTDE data for {age_s:.3f} s (more than "
                              f"{self.settings.stall_periods} periods)")

    # -- commanding ---------------------------------------------------------------------------

    def servo_j(self, q: tuple[float, ...], dt: float) -> bool:
        control = self._require_control()
        if self.mode is Mode.SPEED:
            self.end_streaming()
        self.mode = Mode.SERVO
        s = self.settings
        return self._guarded(lambda: control.servoJ(
            list(q), s.servo_velocity, s.servo_acceleration, dt, s.servo_lookahead_s,
            s.servo_gain))

    def speed_j(self, qd: tuple[float, ...]) -> bool:
        control = self._require_control()
        if self.mode is Mode.SERVO:
            self.end_streaming()
        self.mode = Mode.SPEED
        return self._guarded(
            lambda: control.speedJ(list(qd), self.settings.speed_acceleration, 0.0))

    def end_streaming(self) -> None:
        """servoStop / speedStop: the script leaves its servo or speed thread and decelerates."""
        control = self._require_fresh()
        if self.mode is not Mode.IDLE:
            with self.watchdog.lengthened(control):  # both return once the arm is at rest
                self._leave_mode(control)

    def stop(self) -> None:
        """Leave any streaming mode, then stopJ (synchronous: returns once decelerated)."""
        control = self._require_fresh()
        if self.mode is Mode.IDLE:  # at rest already: stopJ returns within a cycle or two
            control.stopJ(self.settings.stop_deceleration, False)
            return
        with self.watchdog.lengthened(control):
            self._leave_mode(control)
            control.stopJ(self.settings.stop_deceleration, False)

    def _leave_mode(self, control: _sdk.ControlInterface) -> None:
        if self.mode is Mode.SERVO:
            control.servoStop(self.settings.servo_stop_deceleration)
        elif self.mode is Mode.SPEED:
            control.speedStop(self.settings.stop_deceleration)
        self.mode = Mode.IDLE

    def arm_watchdog(self, frequency_hz: float) -> bool:
        """setWatchdog: from now on the controller stops the script if the commands stop.
        False: the script did not confirm it (the status words say why)."""
        return self.watchdog.arm(self._require_fresh(), frequency_hz)

    def kick_watchdog(self) -> None:
        """For a write cycle that sends no setpoint (a setpoint is itself a kick; a kick right
        after one can hide it from the script, see ``watchdog``)."""
        control = self._require_control()
        if self.watchdog.armed:
            self._guarded(control.kickWatchdog)  # fire-and-forget: no answer to wait for

    def disarm_watchdog(self) -> None:
        """Stop the control script if a watchdog is armed (the only way to remove it)."""
        if self.watchdog.armed:
            self.watchdog.disarm(self._require_fresh())

    def set_gripper(self, closed: bool) -> None:
        """Switch the gripper's tool output (high = closed).

        Sent only while the RTDE streams are connected: the IO session cannot notice on its own
        that the controller went away, and its first write after that is lost without an error.
        """
        io, wiring = self._require_io()
        self.gripper_closed = None  # unknown until the write has gone out
        if not self._guarded(lambda: io.setToolDigitalOut(wiring.output, closed)):
            raise LinkDown("ur_rtde could not send the tool digital output")
        self.gripper_closed = closed
        self._gripper_written_ns = time.monotonic_ns()

    def gripper_needs_write(self, closed: bool) -> bool:
        """A change of the commanded state, or a written state that a snapshot taken
        ``GRIPPER_CONFIRM_S`` after the write still does not show (a lost write, or another
        program switched the output): the output is written again then, at most that often."""
        if closed is not self.gripper_closed:
            return True
        settled = self._gripper_read_ns - self._gripper_written_ns > GRIPPER_CONFIRM_S * 1e9
        return settled and self.gripper_output_high is not None and (
            self.gripper_output_high != closed)

    def program_running(self) -> bool:
        """The control session's own view, which is what ur_rtde checks before every command."""
        return self._require_control().isProgramRunning()

    def restart_script(self) -> None:
        """Upload rtde_control again (after a cleared safety stop the old one has ended)."""
        control = self._require_fresh()
        self.watchdog.forget()  # the new script starts without one
        control.reuploadScript()
        deadline = time.monotonic() + SCRIPT_START_TIMEOUT_S
        # Both sessions must have seen it: each gets its own packages, a few ms apart.
        while not (control.isProgramRunning()
                   and self._receive().getRuntimeState() == tables.RuntimeState.PLAYING):
            if time.monotonic() > deadline:
                raise DeviceFault(self.device, f"the control script did not start on the arm "
                                  f"at {self.settings.host}", ReasonCode.CONTROLLER_FAULT)
            time.sleep(POLL_S)
        self.mode = Mode.IDLE

    # -- guards -------------------------------------------------------------------------------

    def _receive(self) -> _sdk.ReceiveInterface:
        if self.receive is None:
            raise LinkDown("the RTDE receive interface is closed")
        return self.receive

    def _require_connected(self) -> _sdk.ReceiveInterface:
        receive = self._receive()
        if not receive.isConnected():
            raise LinkDown("the RTDE receive session closed (controller gone, or silent > 2.5 s)")
        if self.control is not None and not self.control.isConnected():
            raise LinkDown("the RTDE control session closed")
        return receive

    def _guarded(self, send: Callable[[], bool]) -> bool:
        # A write to a socket the controller closed makes ur_rtde reconnect inside the call
        # and raise RuntimeError when that fails: the link is lost either way.
        try:
            return send()
        except RuntimeError as error:
            raise LinkDown(f"ur_rtde: {error}") from error

    def _require_io(self) -> tuple[_sdk.IOInterface, GripperWiring]:
        self._require_connected()
        if self.io is None or self.gripper is None:
            raise LinkDown("the RTDE IO interface is closed (or no gripper is configured)")
        if not self.io.isConnected():
            raise LinkDown("the RTDE IO session closed")
        return self.io, self.gripper

    def _require_control(self) -> _sdk.ControlInterface:
        self._require_connected()
        if self.control is None:
            raise LinkDown("the RTDE control interface is closed")
        return self.control

    def _require_fresh(self) -> _sdk.ControlInterface:
        control = self._require_control()
        if not self._fresh():
            self._require_connected()  # a session that closed during the wait: LinkDown
            raise LinkStalled("no new RTDE data: not sending a command that waits for the arm")
        return control

    def switching_to(self, mode: Mode) -> bool:
        """Whether a setpoint of ``mode`` first ends another streaming mode (a blocking stop)."""
        return self.mode not in (Mode.IDLE, mode)

    def _fresh(self) -> bool:
        """Connected, and the timestamp moves within the stall threshold (usually one period)."""
        receive = self.receive
        if receive is None or not receive.isConnected():
            return False
        first = receive.getTimestamp()
        deadline = time.monotonic() + self.settings.stall_after_s
        while time.monotonic() < deadline:
            if receive.getTimestamp() != first:
                return True
            time.sleep(POLL_S)
        return False


def _close(interface: _sdk.ReceiveInterface | _sdk.ControlInterface, healthy: bool,
           tidy: Callable[[], None]) -> None:
    """Healthy: tidy up and let the destructor disconnect. Unhealthy: disconnect explicitly
    first, because the destructor would sit out the library's read deadline with the GIL held."""
    try:
        if healthy:
            tidy()
        elif interface.isConnected():
            interface.disconnect()
    except RuntimeError:
        pass  # closing goes on regardless; the link is being dropped anyway


def release_io(io: _sdk.IOInterface, healthy: bool) -> None:
    """Disconnect an IO interface, or keep it alive forever if that may not work.

    Its destructor disconnects when the session still counts as connected, and on a session the
    controller has closed that throws inside a C++ destructor: std::terminate. So an interface
    that did not disconnect cleanly is never destroyed, not even at interpreter exit (an extra
    reference nothing releases); that costs one socket. On an unhealthy link disconnect is not
    even tried: it waits for an answer to its "pause" without a deadline.
    """
    if healthy:
        with contextlib.suppress(RuntimeError):  # dropped by the controller: kept, below
            io.disconnect()
    if io.isConnected():
        ctypes.pythonapi.Py_IncRef(ctypes.py_object(io))
