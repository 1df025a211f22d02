"""What ``warden check`` compares on a Dynamixel bus: each servo's control table against the
driver's settings and the manifest's limits. Reads only (one read per item and servo).

- model number: an X-series model this driver knows (read at connect);
- operating mode (11): position for the joints, current-based position for the gripper;
- position limits (48, 52): the servo must take every goal the manifest's limits allow;
- homing offset (20) and drive mode (10): warden calibrates in software (``offsets_rad``,
  ``directions``); a servo that also shifts or mirrors its positions is calibrated twice;
- profile velocity (112): the servo's own speed cap toward a goal must not be below the
  manifest's velocity limit (0: no cap);
- torque (64) on and no hardware error (70), since the bus is active and holding;
- the gripper's reading within its stroke (a reading past an end means its ticks are off).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from drivers.base import ControlConfig
from drivers.dynamixel import tables
from drivers.dynamixel.bus import DynamixelBus
from drivers.dynamixel.messages import ids_text
from drivers.dynamixel.settings import GRIPPER_MAX_OPENING_M, DynamixelSettings
from drivers.dynamixel.units import RAD_PER_TICK, RAD_S_PER_VELOCITY_UNIT, JointCalibration
from drivers.readiness import Finding, judged, not_exercised

GRIPPER_READING_SLACK_M = 0.002
"""A gripper reading this far past an end of its stroke still counts as inside it."""


@dataclass(frozen=True, slots=True)
class ServoConfig:
    """The control-table items one servo reports, as read."""

    operating_mode: int
    drive_mode: int
    homing_offset: int
    min_position: int
    max_position: int
    profile_velocity: int
    torque: int
    hardware_error: int


def read_configuration(bus: DynamixelBus) -> dict[int, ServoConfig]:
    """Every servo's items (device thread only)."""
    return {dxl_id: ServoConfig(
        operating_mode=bus.read_item(dxl_id, tables.OPERATING_MODE),
        drive_mode=bus.read_item(dxl_id, tables.DRIVE_MODE),
        homing_offset=bus.read_item(dxl_id, tables.HOMING_OFFSET),
        min_position=bus.read_item(dxl_id, tables.MIN_POSITION_LIMIT),
        max_position=bus.read_item(dxl_id, tables.MAX_POSITION_LIMIT),
        profile_velocity=bus.read_item(dxl_id, tables.PROFILE_VELOCITY),
        torque=bus.read_item(dxl_id, tables.TORQUE_ENABLE),
        hardware_error=bus.read_item(dxl_id, tables.HARDWARE_ERROR_STATUS),
    ) for dxl_id in bus.settings.all_ids}


@dataclass(frozen=True, slots=True)
class Inspected:
    settings: DynamixelSettings
    calibration: JointCalibration
    control: ControlConfig
    models: Mapping[int, int]
    servos: Mapping[int, ServoConfig]
    gripper_m: float | None
    watchdog_units: int

    def label(self, ids: Sequence[int]) -> str:
        return ("ids " if len(ids) > 1 else "id ") + ids_text(ids, self.settings.gripper_id)

    def grouped(self, value: Callable[[int], str]) -> str:
        """``ids 1, 2, 3: a; id 7 (gripper): b``: servos that report alike, together."""
        groups: dict[str, list[int]] = {}
        for dxl_id in self.settings.all_ids:
            groups.setdefault(value(dxl_id), []).append(dxl_id)
        return "; ".join(f"{self.label(ids)}: {text}" for text, ids in groups.items())


def findings(inspected: Inspected) -> tuple[Finding, ...]:
    return (_models(inspected), _modes(inspected), _limits(inspected), _calibration(inspected),
            _profile_velocity(inspected), _powered(inspected), *_gripper(inspected),
            not_exercised("bus watchdog (98)", f"armed by the first setpoint "
                          f"({inspected.watchdog_units} x 20 ms)" if inspected.watchdog_units
                          else "off (watchdog_periods = 0)",
                          "armed only by a motion setpoint; check sends none"))


def _models(s: Inspected) -> Finding:
    def name(dxl_id: int) -> str:
        model = s.models[dxl_id]
        return f"{model} ({tables.X_SERIES_MODELS.get(model, 'unknown')})"

    unknown = [i for i in s.settings.all_ids if s.models[i] not in tables.X_SERIES_MODELS]
    problems = [f"{s.label(unknown)}: not an X-series model this driver knows"] if unknown else []
    return judged("model number (0)", "an X-series model", s.grouped(name), problems)


def _expected_mode(s: Inspected, dxl_id: int) -> tables.OperatingMode:
    return (tables.OperatingMode.CURRENT_BASED_POSITION if dxl_id == s.settings.gripper_id
            else tables.OperatingMode.POSITION)


def _modes(s: Inspected) -> Finding:
    def mode(value: int) -> str:
        try:
            return f"{value} ({tables.OperatingMode(value).name.lower().replace('_', ' ')})"
        except ValueError:
            return f"{value} (unknown)"

    wrong = [i for i in s.settings.all_ids if s.servos[i].operating_mode != _expected_mode(s, i)]
    expected = "3 (position) for the joints" + (
        ", 5 (current-based position) for the gripper" if s.settings.gripper_id is not None
        else "")
    problems = [f"{s.label(wrong)}: not in the mode configure set"] if wrong else []
    return judged("operating mode (11)", expected,
                  s.grouped(lambda i: mode(s.servos[i].operating_mode)), problems)


def _limits(s: Inspected) -> Finding:
    calibration = s.calibration
    ids = s.settings.ids
    low_q = calibration.q_from_ticks([s.servos[i].min_position for i in ids])
    high_q = calibration.q_from_ticks([s.servos[i].max_position for i in ids])
    slack = RAD_PER_TICK / 2  # a goal is rounded to the nearest tick
    problems = []
    for joint, dxl_id in enumerate(ids):
        low, high = sorted((low_q[joint], high_q[joint]))
        want_low, want_high = s.control.q_lower[joint], s.control.q_upper[joint]
        if want_low < low - slack or want_high > high + slack:
            servo = s.servos[dxl_id]
            problems.append(f"joint {joint} (id {dxl_id}): the manifest allows [{want_low:.3f}, "
                            f"{want_high:.3f}] rad, {servo.min_position}..{servo.max_position} "
                            f"ticks [{low:.3f}, {high:.3f}] rad")
    if problems:
        problems.append("the servos refuse goals beyond their limits: narrow the manifest's "
                        "robot.position_limits or widen the servos' (48, 52)")
    measured = s.grouped(lambda i: f"{s.servos[i].min_position}..{s.servos[i].max_position}")
    return judged("position limits (52, 48)", "ticks that allow the manifest's joint limits",
                  measured, problems)


def _calibration(s: Inspected) -> Finding:
    problems = []
    for joint, dxl_id in enumerate(s.settings.ids):
        servo = s.servos[dxl_id]
        device_shifts = servo.homing_offset != 0 or bool(
            servo.drive_mode & tables.DRIVE_MODE_REVERSE)
        manifest_shifts = s.settings.offsets_rad[joint] != 0.0 or s.settings.directions[joint] < 0
        if device_shifts and manifest_shifts:
            problems.append(f"joint {joint} (id {dxl_id}): the servo shifts or mirrors its "
                            "positions itself and offsets_rad/directions do it again")

    def measured(dxl_id: int) -> str:
        servo = s.servos[dxl_id]
        turn = "reverse" if servo.drive_mode & tables.DRIVE_MODE_REVERSE else "normal"
        return f"offset {servo.homing_offset}, {turn}"

    return judged("homing offset (20), drive mode (10)",
                  "0 and normal where offsets_rad/directions calibrate the joint",
                  s.grouped(measured), problems)


def _profile_velocity(s: Inspected) -> Finding:
    problems = []
    for joint, dxl_id in enumerate(s.settings.ids):
        units = s.servos[dxl_id].profile_velocity
        cap = units * RAD_S_PER_VELOCITY_UNIT
        if units and cap < s.control.v_max[joint]:
            problems.append(f"joint {joint} (id {dxl_id}): {units} units cap it at {cap:.3g} "
                            f"rad/s, below the manifest's {s.control.v_max[joint]:.3g} rad/s: "
                            "it would lag the setpoints")
    return judged("profile velocity (112)", "0 (no cap) or at least the manifest's velocity "
                  "limit", s.grouped(lambda i: str(s.servos[i].profile_velocity)), problems)


def _powered(s: Inspected) -> Finding:
    off = [i for i in s.settings.all_ids if s.servos[i].torque != 1]
    errors = [i for i in s.settings.all_ids if s.servos[i].hardware_error]
    problems = [f"{s.label(off)}: torque off"] if off else []
    problems += [f"id {i}: hardware error "
                 f"{', '.join(tables.hardware_error_names(s.servos[i].hardware_error))}"
                 for i in errors]
    return judged("torque (64), hardware error (70)", "torque on, no error (active, holding)",
                  s.grouped(lambda i: f"torque {s.servos[i].torque}, error "
                            f"0x{s.servos[i].hardware_error:02x}"), problems)


def _gripper(s: Inspected) -> tuple[Finding, ...]:
    if s.gripper_m is None:
        return ()
    opening = s.gripper_m
    inside = -GRIPPER_READING_SLACK_M <= opening <= GRIPPER_MAX_OPENING_M + (
        GRIPPER_READING_SLACK_M) and math.isfinite(opening)
    problems = [] if inside else [
        "past an end of the stroke: check gripper_open_ticks and gripper_closed_ticks"]
    return (judged("gripper opening", f"within [0, {GRIPPER_MAX_OPENING_M}] m",
                   f"{opening:.4f} m", problems),)

