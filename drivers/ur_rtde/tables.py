"""UR status words and their meaning for warden: plain data, read by the driver, tested alone.

Numbers from the UR RTDE guide (robot_mode, safety_status_bits, runtime_state) and from
ur_rtde 1.6.5 (the client-side parameter ranges it enforces with ValueError).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from assurance.reasons import ReasonCode


class RobotMode(IntEnum):
    NO_CONTROLLER = -1
    DISCONNECTED = 0
    CONFIRM_SAFETY = 1
    BOOTING = 2
    POWER_OFF = 3
    POWER_ON = 4
    IDLE = 5
    BACKDRIVE = 6
    RUNNING = 7
    UPDATING_FIRMWARE = 8


class SafetyBit(IntEnum):
    NORMAL = 0
    REDUCED = 1
    PROTECTIVE_STOP = 2
    RECOVERY = 3
    SAFEGUARD_STOP = 4
    SYSTEM_EMERGENCY_STOP = 5
    ROBOT_EMERGENCY_STOP = 6
    EMERGENCY_STOP = 7
    VIOLATION = 8
    FAULT = 9
    STOPPED_DUE_TO_SAFETY = 10


class RuntimeState(IntEnum):
    STOPPING = 0
    STOPPED = 1
    PLAYING = 2
    PAUSING = 3
    PAUSED = 4
    RESUMING = 5


E_STOP_BITS = (SafetyBit.SYSTEM_EMERGENCY_STOP, SafetyBit.ROBOT_EMERGENCY_STOP,
               SafetyBit.EMERGENCY_STOP)
"""Any of these: the arm is in an emergency stop (the CONTROLLER_STOP path with E_STOP)."""

SAFETY_STOP_BITS = (SafetyBit.PROTECTIVE_STOP, SafetyBit.RECOVERY, SafetyBit.SAFEGUARD_STOP,
                    SafetyBit.VIOLATION, SafetyBit.FAULT, SafetyBit.STOPPED_DUE_TO_SAFETY)
"""Any of these: the safety system stopped the arm; it will not follow setpoints."""

# ur_rtde 1.6.5 refuses values outside these ranges with ValueError before sending anything;
# settings are checked against the same ranges so a manifest cannot get that far.
LOOKAHEAD_RANGE_S = (0.03, 0.2)
GAIN_RANGE = (100.0, 2000.0)
JOINT_VELOCITY_RANGE = (0.0, 3.14)
JOINT_ACCELERATION_RANGE = (0.0, 40.0)
TOOL_ACCELERATION_RANGE = (0.0, 10.0)

CONTROLLER_CYCLE_S = 0.002
"""e-Series controller cycle; servoj's time argument must not be shorter."""
MAX_RTDE_FREQUENCY_HZ = 500.0

MIN_VERSION = (5, 4, 0)
SUPPORTED_MAJOR = 5
"""e-Series PolyScope 5.4+: 500 Hz RTDE and every register the control script uses. CB3 (3.x,
125 Hz) and PolyScope X (10.x, no script port) are different protocols for this driver."""

DOF = 6

RECEIVE_VARIABLES = [
    "timestamp", "actual_q", "actual_qd", "actual_TCP_force", "robot_mode",
    "safety_status_bits", "runtime_state", "speed_scaling", "target_speed_fraction",
]
"""The RTDE outputs the driver subscribes to (a short recipe keeps every read cheap)."""

TOOL_DIGITAL_OUTPUTS = (0, 1)
"""Tool digital outputs of an e-Series tool flange (bits 16-17 of actual_digital_output_bits)."""
TOOL_OUTPUT_SHIFT = 16
"""Bit of tool digital output 0 in actual_digital_output_bits."""
GRIPPER_FEEDBACK_INPUTS = {
    "standard_analog_input0": "getStandardAnalogInput0",
    "standard_analog_input1": "getStandardAnalogInput1",
}
"""RTDE analog inputs a gripper's position signal can be read from, and their ur_rtde getter.

Only the control box's standard inputs: ur_rtde 1.6.5's receive interface has no getter for the
tool analog inputs, and its own type table does not know ``tool_analog_input0`` (it could not
unpack a package that carried it)."""
GRIPPER_MAX_OPENING_M = 0.085
"""Fully open two-finger gripper (Robotiq 2F-85 class), metres between the pads."""


def version_supported(version: tuple[int, ...]) -> bool:
    return version[0] == SUPPORTED_MAJOR and tuple(version[:3]) >= MIN_VERSION


@dataclass(frozen=True, slots=True)
class Fault:
    reason: ReasonCode
    detail: str


def _set_bits(word: int, bits: tuple[SafetyBit, ...]) -> list[str]:
    return [bit.name for bit in bits if word >> bit & 1]


def device_faults(safety_bits: int, robot_mode: int, runtime_state: int,
                  streaming: bool, watchdog_s: float | None = None) -> list[Fault]:
    """What the status words say is wrong, most severe first.

    Safety stops always count. Robot mode and program state count only while streaming:
    an idle, connected arm with no program running is not at fault. ``watchdog_s``: the RTDE
    watchdog the driver armed (None: not armed); a control script that stopped with it armed
    and no safety stop was most likely stopped by it (WATCHDOG): the status words look the same
    after a "stop" from the dashboard, which the driver never sends while streaming.
    """
    faults: list[Fault] = []
    if e_stops := _set_bits(safety_bits, E_STOP_BITS):
        faults.append(Fault(ReasonCode.E_STOP, "emergency stop: " + ", ".join(e_stops)))
    if stops := _set_bits(safety_bits, SAFETY_STOP_BITS):
        faults.append(Fault(ReasonCode.CONTROLLER_FAULT, "safety stop: " + ", ".join(stops)))
    if streaming and robot_mode != RobotMode.RUNNING:
        mode = _name(RobotMode, robot_mode)
        faults.append(Fault(ReasonCode.CONTROLLER_FAULT, f"robot mode {mode}"))
    if streaming and runtime_state != RuntimeState.PLAYING:
        faults.append(_script_stopped(runtime_state, watchdog_s if not faults else None))
    return faults


def _script_stopped(runtime_state: int, watchdog_s: float | None) -> Fault:
    state = _name(RuntimeState, runtime_state)
    if watchdog_s is None or runtime_state != RuntimeState.STOPPED:
        return Fault(ReasonCode.CONTROLLER_FAULT,
                     f"control script not running (runtime state {state})")
    return Fault(ReasonCode.WATCHDOG,
                 f"the controller stopped the control script (runtime state {state}, no safety "
                 f"stop) with the RTDE watchdog armed: no command reached it for more than "
                 f"{watchdog_s * 1e3:.0f} ms; the arm was stopped by the controller")


def _name(kind: type[IntEnum], value: int) -> str:
    try:
        return kind(value).name
    except ValueError:
        return str(value)
