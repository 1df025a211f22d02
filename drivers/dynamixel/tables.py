"""The X-series control table (Protocol 2.0) as data, from the Robotis e-Manual.

Only the items the driver touches are listed; addresses are shared by every X-series model
(XL330, XL430, XC430, XM430, XM540, XH430, XH540). What differs per model (current resolution,
which operating modes exist) lives in settings or in :data:`X_SERIES_MODELS`.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, IntFlag
from types import MappingProxyType


@dataclass(frozen=True, slots=True)
class Register:
    name: str
    address: int
    size: int
    signed: bool = False


MODEL_NUMBER = Register("Model Number", 0, 2)
FIRMWARE_VERSION = Register("Firmware Version", 6, 1)
DRIVE_MODE = Register("Drive Mode", 10, 1)
DRIVE_MODE_REVERSE = 0x01
"""Drive Mode bit 0: the servo turns the other way round (positions mirrored)."""
OPERATING_MODE = Register("Operating Mode", 11, 1)
HOMING_OFFSET = Register("Homing Offset", 20, 4, signed=True)
"""Added by the servo to every Present Position it reports (and taken off every goal)."""
MAX_POSITION_LIMIT = Register("Max Position Limit", 48, 4)
MIN_POSITION_LIMIT = Register("Min Position Limit", 52, 4)
TORQUE_ENABLE = Register("Torque Enable", 64, 1)
HARDWARE_ERROR_STATUS = Register("Hardware Error Status", 70, 1)
BUS_WATCHDOG = Register("Bus Watchdog", 98, 1, signed=True)
"""0: off (writing 0 also clears a Bus Watchdog Error); 1..127: armed, in BUS_WATCHDOG_UNIT_S;
-1: expired, the servo stopped and refuses goal values (Data Range Error) until 0 is written.
Counts only while Torque Enable is 1; every instruction packet feeds it. Firmware v38 on."""
BUS_WATCHDOG_UNIT_S = 0.020
BUS_WATCHDOG_MAX_UNITS = 127
BUS_WATCHDOG_ERROR = -1
GOAL_CURRENT = Register("Goal Current", 102, 2, signed=True)
GOAL_CURRENT_MAX_UNITS = 2047
"""The largest Current Limit of the X series (XM540); each servo refuses a Goal Current above
its own Current Limit (1193 on an XM430-W350) with a data-limit error."""
PROFILE_VELOCITY = Register("Profile Velocity", 112, 4)
"""In position mode, the top speed of the servo's own profile toward each goal (0.229 rev/min
units); 0: no profile, the servo goes at full speed."""
GOAL_POSITION = Register("Goal Position", 116, 4, signed=True)
PRESENT_CURRENT = Register("Present Current", 126, 2, signed=True)
PRESENT_VELOCITY = Register("Present Velocity", 128, 4, signed=True)
PRESENT_POSITION = Register("Present Position", 132, 4, signed=True)

STATE_BLOCK = (PRESENT_CURRENT, PRESENT_VELOCITY, PRESENT_POSITION)
"""Read together every cycle: one contiguous block, so one (fast) sync read fetches all three."""
STATE_BLOCK_START = PRESENT_CURRENT.address
STATE_BLOCK_SIZE = PRESENT_POSITION.address + PRESENT_POSITION.size - STATE_BLOCK_START


class OperatingMode(IntEnum):
    CURRENT = 0
    VELOCITY = 1
    POSITION = 3
    EXTENDED_POSITION = 4
    CURRENT_BASED_POSITION = 5
    PWM = 16


class HardwareError(IntFlag):
    """Bits of Hardware Error Status (70). Any of them latches until reboot or power cycle."""

    INPUT_VOLTAGE = 0x01
    OVERHEATING = 0x04
    MOTOR_ENCODER = 0x08
    ELECTRICAL_SHOCK = 0x10
    OVERLOAD = 0x20


HARDWARE_ERROR_NAMES = MappingProxyType({
    HardwareError.INPUT_VOLTAGE: "input voltage out of range",
    HardwareError.OVERHEATING: "overheating",
    HardwareError.MOTOR_ENCODER: "motor encoder error",
    HardwareError.ELECTRICAL_SHOCK: "electrical shock (short circuit or power failure)",
    HardwareError.OVERLOAD: "overload",
})

ERRBIT_ALERT = 0x80
"""Status packet error byte: the servo has a hardware error; read Hardware Error Status."""

TICKS_PER_REV = 4096
CENTRE_TICK = 2048
POSITION_MODE_TICKS = (0, 4095)
"""Goal Position range in position mode (one turn); the servo refuses goals outside it."""
VELOCITY_UNIT_RPM = 0.229
"""Present Velocity counts 0.229 rev/min on every X-series model."""
BAUD_RATES = (9600, 57600, 115200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)
"""The rates ``baud`` may name: those an X-series servo's Baud Rate (8) can be set to (values 0
to 6; 7 is 4.5 Mbps) that dynamixel_sdk's PortHandler also opens (its fixed list stops at
4 Mbps and holds rates no X-series servo speaks, such as 19200 or 2.5 Mbps)."""

X_SERIES_MODELS = MappingProxyType({
    1020: "XM430-W350",
    1030: "XM430-W210",
    1060: "XL430-W250",
    1070: "XC430-W150",
    1120: "XM540-W270",
    1190: "XL330-M077",
    1200: "XL330-M288",
})
"""Model numbers (address 0) this driver knows to share the table above."""


def hardware_error_names(status: int) -> list[str]:
    """The human names of the bits set in a Hardware Error Status byte, lowest bit first."""
    names = [text for bit, text in HARDWARE_ERROR_NAMES.items() if status & bit]
    unknown = status & ~sum(HARDWARE_ERROR_NAMES)
    if unknown:
        names.append(f"unknown bits 0x{unknown:02x}")
    return names
