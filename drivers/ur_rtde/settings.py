"""Settings of one UR arm, from its manifest table (the one with ``driver = "ur_rtde"``)."""

from __future__ import annotations

import ipaddress
from collections.abc import Mapping
from typing import Annotated, Any

from msgspec import Meta

from drivers.settings import Settings, read_table
from drivers.ur_rtde import tables

WATCHDOG_PERIODS_RANGE = (2, 10_000)
"""An armed watchdog waits at least two periods (one late tick must not stop the arm); 0 is
"off"."""
FEEDBACK_MAX = 100.0
"""Bound on a gripper feedback reading: a standard analog input reads 0 to 10 V or 0.004 to
0.02 A; anything beyond a hundred is a unit mistake (and NaN fails the comparison too)."""
Feedback = Annotated[float, Meta(ge=-FEEDBACK_MAX, le=FEEDBACK_MAX)]



def _within(bounds: tuple[float, float]) -> Meta:
    return Meta(ge=bounds[0], le=bounds[1])


class URSettings(Settings, frozen=True):
    """The table of one UR arm; every range is ur_rtde's own (docs/manifest.md)."""

    host: str
    """Controller address (the library's ports are fixed: 30004, 29999, 30003)."""
    frequency_hz: Annotated[float, Meta(ge=1.0, le=tables.MAX_RTDE_FREQUENCY_HZ)] = 500.0
    """RTDE output frequency the driver subscribes to (at most 500 Hz on e-Series)."""
    servo_lookahead_s: Annotated[float, _within(tables.LOOKAHEAD_RANGE_S)] = 0.1
    """servoJ lookahead time: longer is smoother and lags more. ur_rtde range [0.03, 0.2]."""
    servo_gain: Annotated[float, _within(tables.GAIN_RANGE)] = 300.0
    """servoJ proportional gain. ur_rtde range [100, 2000]."""
    servo_velocity: Annotated[float, _within(tables.JOINT_VELOCITY_RANGE)] = 0.5
    """servoJ speed argument (unused by current controllers, still range-checked [0, 3.14])."""
    servo_acceleration: Annotated[float, _within(tables.JOINT_ACCELERATION_RANGE)] = 0.5
    """servoJ acceleration argument (unused by current controllers, range [0, 40])."""
    speed_acceleration: Annotated[float, _within(tables.JOINT_ACCELERATION_RANGE)] = 0.5
    """speedJ acceleration of the leading axis, rad/s², range [0, 40]."""
    stop_deceleration: Annotated[float, _within(tables.JOINT_ACCELERATION_RANGE)] = 2.0
    """stopJ and speedStop deceleration of the leading axis, rad/s², range [0, 40]."""
    servo_stop_deceleration: Annotated[float, _within(tables.TOOL_ACCELERATION_RANGE)] = 10.0
    """servoStop deceleration of the tool, m/s², range [0, 10]."""
    connect_timeout_s: Annotated[float, Meta(ge=0.1, le=60.0)] = 5.0
    """Bound on the pre-flight check and on building each ur_rtde interface."""
    call_timeout_s: Annotated[float, Meta(ge=0.01, le=10.0)] = 0.5
    """Bound on a read or a streamed setpoint (ur_rtde's own timeouts reach 300 s)."""
    stop_timeout_s: Annotated[float, Meta(ge=0.1, le=60.0)] = 5.0
    """Bound on commands that return once the arm has decelerated (stopJ, servoStop, ...)."""
    stall_periods: Annotated[int, Meta(ge=2, le=10_000)] = 50
    """No new RTDE timestamp for this many output periods while reading → WATCHDOG."""
    watchdog_periods: Annotated[int, Meta(ge=0, le=WATCHDOG_PERIODS_RANGE[1])] = 25
    """Controller-side RTDE watchdog (ur_rtde ``setWatchdog``): the controller stops the control
    script, and with it the arm, when no command reaches it for this many control periods
    (50 ms at 500 Hz: on a loaded 2-core test machine the loop went silent for over 20 ms
    once in a while). Armed by the first motion setpoint after activation, fed by every
    setpoint, removed on deactivate. 0 switches it off (then nothing stops the arm if warden
    dies while streaming a velocity or a far target)."""
    reconnect_attempts: Annotated[int, Meta(ge=0, le=10)] = 2
    """Extra connect attempts after the first one fails to reach the controller."""
    reconnect_backoff_s: Annotated[float, Meta(ge=0.0, le=10.0)] = 0.5
    gripper_output: int | None = None
    """Tool digital output (0 or 1) driving a two-finger gripper that closes while it is high;
    none: the arm has no gripper and ``Command.gripper`` is ignored. Binary: a commanded opening
    below half of ``gripper_max_opening_m`` closes it, half or more opens it."""
    gripper_feedback: str = "standard_analog_input0"
    """Analog input carrying the gripper's position signal: standard_analog_input0 or 1 (the
    tool analog inputs cannot be read through ur_rtde 1.6.5)."""
    gripper_feedback_closed: Feedback = 0.0
    """That input's reading with the gripper closed (0 m), in the controller's unit for it
    (volts on a 0-10 V input)."""
    gripper_feedback_open: Feedback = 10.0
    """That input's reading with the gripper fully open (``gripper_max_opening_m``)."""
    gripper_max_opening_m: Annotated[float, Meta(gt=0.0, le=0.5)] = (
        tables.GRIPPER_MAX_OPENING_M)

    def __post_init__(self) -> None:
        super().__post_init__()
        problems = _problems(self)
        if problems:
            raise ValueError("; ".join(problems))

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any], where: str) -> URSettings:
        """Build from a manifest table; unknown keys and bad values raise SettingsError."""
        return read_table(cls, table, where)

    @property
    def rtde_period_s(self) -> float:
        return 1.0 / self.frequency_hz

    @property
    def stall_after_s(self) -> float:
        return self.stall_periods * self.rtde_period_s

    def watchdog_frequency_hz(self, control_period_s: float) -> float | None:
        """``setWatchdog``'s min_frequency for this control period; None: switched off."""
        if self.watchdog_periods == 0:
            return None
        return 1.0 / (self.watchdog_periods * control_period_s)


def _problems(s: URSettings) -> list[str]:
    """The rules the fields' own bounds cannot say (those are checked first, one by one)."""
    problems = []
    low, high = WATCHDOG_PERIODS_RANGE
    if s.watchdog_periods != 0 and not low <= s.watchdog_periods <= high:
        problems.append(f"watchdog_periods = {s.watchdog_periods} is neither 0 (off) nor within "
                        f"[{low}, {high}]")
    if not s.host.strip():
        problems.insert(0, "host is empty: set it to the controller's address")
    problems += _gripper_problems(s)
    if not problems and s.stall_after_s >= s.call_timeout_s:
        problems.append(f"stall_periods = {s.stall_periods} at {s.frequency_hz} Hz is "
                        f"{s.stall_after_s:.3f} s, not shorter than call_timeout_s = "
                        f"{s.call_timeout_s}: a stall would look like a slow call")
    return problems


def _gripper_problems(s: URSettings) -> list[str]:
    problems = []
    if s.gripper_output is not None and s.gripper_output not in tables.TOOL_DIGITAL_OUTPUTS:
        problems.append(f"gripper_output = {s.gripper_output} is not a tool digital output "
                        f"(one of {', '.join(map(str, tables.TOOL_DIGITAL_OUTPUTS))})")
    if s.gripper_feedback not in tables.GRIPPER_FEEDBACK_INPUTS:
        hint = (": ur_rtde 1.6.5 cannot read the tool analog inputs, wire the signal to a "
                "standard analog input" if s.gripper_feedback.startswith("tool_") else "")
        problems.append(f"gripper_feedback = {s.gripper_feedback!r} is not one of "
                        f"{', '.join(tables.GRIPPER_FEEDBACK_INPUTS)}{hint}")
    closed, opened = s.gripper_feedback_closed, s.gripper_feedback_open
    if closed == opened:
        problems.append(f"gripper_feedback_closed = {closed} and gripper_feedback_open = "
                        f"{opened} must be two different readings")
    return problems


def device_identity(settings: URSettings) -> str:
    """The controller ``settings`` address, the same string for every table that names it (an
    IP address in its canonical form; a host name lower-cased, not resolved)."""
    host = settings.host.strip()
    try:
        host = str(ipaddress.ip_address(host))
    except ValueError:
        host = host.lower().rstrip(".")
    return f"UR controller {host}"


def device_watchdog(settings: URSettings) -> str | None:
    """What stops the arm when warden's commands stop, as ``settings`` configure it; None: off."""
    if settings.watchdog_periods <= 0:
        return None
    return (f"the controller's RTDE watchdog: no setpoint for {settings.watchdog_periods} "
            "control periods and the control script stops")


def device_watchdog_ms(settings: URSettings, control_period_ms: float) -> float | None:
    """How long after warden's last command :func:`device_watchdog` stops the arm, in ms;
    None: off."""
    if settings.watchdog_periods <= 0:
        return None
    return settings.watchdog_periods * control_period_ms


ADDRESS_KEYS: Mapping[str, str] = {"host": "127.0.0.1"}
"""The settings that say where the device is, with placeholders (``Driver.address_keys``)."""
