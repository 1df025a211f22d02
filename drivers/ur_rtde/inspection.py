"""What ``warden check`` compares on a UR arm: what the controller reports over RTDE against
what a run needs of it. Reads only: the receive interface's getters, no command.

- the controller's software: e-Series PolyScope 5.4 or newer (the pre-flight probe read it);
- robot mode RUNNING, the safety system in NORMAL mode (no stop, not REDUCED);
- the control script (rtde_control) PLAYING, as activation left it;
- the speed slider and the trajectory limiter's scaling at 100 %: below it, the arm follows the
  core's servoJ targets slower than the core plans them, and the core sees divergence;
- the gripper's feedback input within the stroke (``gripper_feedback_closed``/``_open``).

RTDE does not carry the safety configuration's joint limits: the kernel compares the measured
joint positions with the manifest's limits instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from drivers.readiness import Finding, judged, not_exercised
from drivers.ur_rtde import tables
from drivers.ur_rtde.link import Link, LinkDown
from drivers.ur_rtde.settings import URSettings

FULL_SPEED = 0.999
"""A slider or scaling at or above this counts as 100 %."""
GRIPPER_READING_SLACK_M = 0.002


@dataclass(frozen=True, slots=True)
class ArmStatus:
    robot_mode: int
    safety_bits: int
    runtime_state: int
    speed_slider: float
    """target_speed_fraction: the speed slider on the teach pendant (or set over RTDE)."""
    speed_scaling: float
    """The trajectory limiter's own scaling (below 1 when the controller slows motion)."""
    gripper_m: float | None


def read_status(link: Link) -> ArmStatus:
    """One snapshot plus the two speed factors it multiplies (device thread only).

    Raises:
        LinkDown: the receive interface is closed.
        LinkStalled: the controller stopped sending.
    """
    snapshot = link.snapshot()
    receive = link.receive
    if receive is None:
        raise LinkDown("the RTDE receive interface is closed")
    return ArmStatus(robot_mode=snapshot.robot_mode, safety_bits=snapshot.safety_bits,
                     runtime_state=snapshot.runtime_state,
                     speed_slider=receive.getTargetSpeedFraction(),
                     speed_scaling=receive.getSpeedScaling(), gripper_m=snapshot.gripper_opening)


def findings(settings: URSettings, version: tuple[int, ...], status: ArmStatus,
             watchdog_hz: float | None) -> tuple[Finding, ...]:
    return (
        judged("controller software", "e-Series PolyScope "
               f"{'.'.join(map(str, tables.MIN_VERSION))} or newer 5.x",
               ".".join(map(str, version)), [] if tables.version_supported(version)
               else ["not a version this driver speaks"]),
        _robot_mode(status), _safety(status), _script(status), _speed(status),
        *_gripper(settings, status),
        not_exercised("joint limits of the safety configuration", "not narrower than the "
                      "manifest's", "RTDE does not report them; the measured positions are "
                      "checked against the manifest's limits"),
        not_exercised("RTDE watchdog (setWatchdog)", f"{watchdog_hz:g} Hz, armed by the first "
                      "motion setpoint" if watchdog_hz else "off (watchdog_periods = 0)",
                      "armed only by a motion setpoint; check sends none"),
    )


def _robot_mode(status: ArmStatus) -> Finding:
    mode = _name(tables.RobotMode, status.robot_mode)
    problems = [] if status.robot_mode == tables.RobotMode.RUNNING else [
        "the arm is not powered on with its brakes released"]
    return judged("robot mode", "RUNNING", mode, problems)


def _safety(status: ArmStatus) -> Finding:
    bits = [bit.name for bit in tables.SafetyBit if status.safety_bits >> bit & 1]
    stops = [name for name in bits if name != tables.SafetyBit.NORMAL.name]
    problems = []
    if stops:
        problems.append(f"{', '.join(stops)}: the safety system "
                        + ("runs on its reduced limits" if stops == ["REDUCED"]
                           else "has stopped the arm"))
    elif tables.SafetyBit.NORMAL.name not in bits:
        problems.append("not in normal mode")
    return judged("safety status", "NORMAL", ", ".join(bits) or "none", problems)


def _script(status: ArmStatus) -> Finding:
    state = _name(tables.RuntimeState, status.runtime_state)
    problems = [] if status.runtime_state == tables.RuntimeState.PLAYING else [
        "the control script is not running: setpoints would not be followed"]
    return judged("control script (runtime state)", "PLAYING", state, problems)


def _speed(status: ArmStatus) -> Finding:
    problems = []
    if status.speed_slider < FULL_SPEED:
        problems.append(f"the speed slider is at {100 * status.speed_slider:.0f} %")
    if status.speed_scaling < FULL_SPEED:
        problems.append(f"the controller scales motion to {100 * status.speed_scaling:.0f} %")
    if problems:
        problems.append("the arm would follow the core's setpoints slower than planned")
    return judged("speed slider, speed scaling", "100 %, 100 %",
                  f"{100 * status.speed_slider:.0f} %, {100 * status.speed_scaling:.0f} %",
                  problems)


def _gripper(settings: URSettings, status: ArmStatus) -> tuple[Finding, ...]:
    if status.gripper_m is None:
        return ()
    opening, stroke = status.gripper_m, settings.gripper_max_opening_m
    inside = math.isfinite(opening) and (
        -GRIPPER_READING_SLACK_M <= opening <= stroke + GRIPPER_READING_SLACK_M)
    problems = [] if inside else [
        f"past an end of the stroke: check {settings.gripper_feedback}'s wiring and "
        "gripper_feedback_closed/gripper_feedback_open"]
    return (judged(f"gripper opening ({settings.gripper_feedback})",
                   f"within [0, {stroke}] m", f"{opening:.4f} m", problems),)


def _name(kind: type[IntEnum], value: int) -> str:
    try:
        return kind(value).name
    except ValueError:
        return str(value)
