"""CiA 301 / CiA 402 as plain data: object indices, drive states, controlword commands, EMCY codes.

The driver decodes what a drive reports with these tables. The emulator in ``stubs/cia402_drive``
has its own, written separately from the standard (a table shared by both sides could agree
with itself and still be wrong); tests/drivers/test_canopen402_tables.py checks each against
canopen's own ``State402`` masks and transition commands.
"""

from __future__ import annotations

import struct
from enum import IntEnum, StrEnum
from pathlib import Path

DEFAULT_EDS = Path(__file__).with_name("cia402_drive.eds")
"""EDS of a generic CSP servo drive: the dictionary the emulator serves (it builds its own in
code; tests/drivers/test_cia402_dictionary.py checks that this file describes it)."""

DEVICE_PROFILE_402 = 402
"""Low 16 bits of 0x1000 (device type) on a drive that implements CiA 402."""


class Index(IntEnum):
    DEVICE_TYPE = 0x1000
    ERROR_REGISTER = 0x1001
    COMM_CYCLE_PERIOD = 0x1006
    """SYNC interval in microseconds; the drive interpolates (and the emulator steps) by it."""
    HEARTBEAT_CONSUMER = 0x1016
    """Consumer heartbeat time: per sub-index, producer node id << 16 | time in ms."""
    HEARTBEAT_TIME = 0x1017
    ABORT_CONNECTION_OPTION = 0x6007
    ERROR_CODE = 0x603F
    CONTROLWORD = 0x6040
    STATUSWORD = 0x6041
    QUICK_STOP_OPTION = 0x605A
    MODES_OF_OPERATION = 0x6060
    MODES_DISPLAY = 0x6061
    POSITION_ACTUAL = 0x6064
    FOLLOWING_ERROR_WINDOW = 0x6065
    VELOCITY_ACTUAL = 0x606C
    RATED_TORQUE = 0x6076
    """Motor rated torque in mN·m; 0x6077 is in thousandths of it."""
    TORQUE_ACTUAL = 0x6077
    TARGET_POSITION = 0x607A
    SOFTWARE_LIMITS = 0x607D
    MAX_PROFILE_VELOCITY = 0x607F
    """In position units (here: counts) per second."""
    POSITION_ENCODER_RESOLUTION = 0x608F
    """Sub-index 1 encoder increments per sub-index 2 motor revolutions."""
    GEAR_RATIO = 0x6091
    """Sub-index 1 motor revolutions per sub-index 2 shaft revolutions."""
    INTERPOLATION_PERIOD = 0x60C2
    SUPPORTED_MODES = 0x6502


class Mode(IntEnum):
    """Modes of operation (0x6060/0x6061) this project uses."""

    NO_MODE = 0
    CYCLIC_SYNCHRONOUS_POSITION = 8


CSP_MODE_NAME = "CYCLIC SYNCHRONOUS POSITION"
"""The name canopen's ``BaseNode402.op_mode`` uses for mode 8."""

SUPPORTED_MODE_BITS = {Mode.CYCLIC_SYNCHRONOUS_POSITION: 0x80}
"""Bit of each mode in 0x6502 (supported drive modes)."""


class DriveState(StrEnum):
    """CiA 402 power drive states, spelled as canopen's ``BaseNode402.state`` spells them."""

    NOT_READY_TO_SWITCH_ON = "NOT READY TO SWITCH ON"
    SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
    READY_TO_SWITCH_ON = "READY TO SWITCH ON"
    SWITCHED_ON = "SWITCHED ON"
    OPERATION_ENABLED = "OPERATION ENABLED"
    QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
    FAULT_REACTION_ACTIVE = "FAULT REACTION ACTIVE"
    FAULT = "FAULT"
    UNKNOWN = "UNKNOWN"


# Statusword bits 0-3, 5 and 6 identify the state (CiA 402-2, table 30); the order matters
# because the masks overlap.
STATUSWORD_PATTERNS: tuple[tuple[DriveState, int, int], ...] = (
    (DriveState.NOT_READY_TO_SWITCH_ON, 0x4F, 0x00),
    (DriveState.SWITCH_ON_DISABLED, 0x4F, 0x40),
    (DriveState.READY_TO_SWITCH_ON, 0x6F, 0x21),
    (DriveState.SWITCHED_ON, 0x6F, 0x23),
    (DriveState.OPERATION_ENABLED, 0x6F, 0x27),
    (DriveState.QUICK_STOP_ACTIVE, 0x6F, 0x07),
    (DriveState.FAULT_REACTION_ACTIVE, 0x4F, 0x0F),
    (DriveState.FAULT, 0x4F, 0x08),
)

STATE_BITS: dict[DriveState, int] = {
    DriveState.NOT_READY_TO_SWITCH_ON: 0x00,
    DriveState.SWITCH_ON_DISABLED: 0x40,
    DriveState.READY_TO_SWITCH_ON: 0x21,
    DriveState.SWITCHED_ON: 0x33,
    DriveState.OPERATION_ENABLED: 0x37,
    DriveState.QUICK_STOP_ACTIVE: 0x17,
    DriveState.FAULT_REACTION_ACTIVE: 0x0F,
    DriveState.FAULT: 0x08,
}
"""Statusword bits a drive reports in each state (bit 4, voltage enabled, set where powered)."""


class StatusBit(IntEnum):
    REMOTE = 1 << 9
    TARGET_REACHED = 1 << 10
    FOLLOWS_COMMAND = 1 << 12
    """In CSP: the drive follows the target position it receives."""
    FOLLOWING_ERROR = 1 << 13


class Controlword(IntEnum):
    """Controlword values for the device-control commands (CiA 402-2, table 31)."""

    DISABLE_VOLTAGE = 0x00
    QUICK_STOP = 0x02
    SHUTDOWN = 0x06
    SWITCH_ON = 0x07
    ENABLE_OPERATION = 0x0F
    FAULT_RESET = 0x80


def decode_state(statusword: int) -> DriveState:
    for state, mask, value in STATUSWORD_PATTERNS:
        if statusword & mask == value:
            return state
    return DriveState.UNKNOWN


QUICK_STOP_HOLD = 6
"""0x605A value: slow down on the quick-stop ramp, then *stay* in QUICK STOP ACTIVE (torque on)."""


class AbortConnection(IntEnum):
    """0x6007 values (CiA 402-2): what a drive does when its connection is lost (bus-off, a
    heartbeat or life guarding event, NMT STOPPED, reset application or communication)."""

    NO_ACTION = 0
    FAULT_SIGNAL = 1
    DISABLE_VOLTAGE = 2
    QUICK_STOP = 3


class NmtState(IntEnum):
    """NMT states as a heartbeat reports them (toggle bit masked)."""

    BOOT_UP = 0
    STOPPED = 4
    OPERATIONAL = 5
    PRE_OPERATIONAL = 127


EMCY_HEARTBEAT = 0x8130
"""A drive's heartbeat consumer missed its producer (CiA 301): warden's, once armed."""

# A few EMCY codes of CiA 402 (annex) that drives and the emulator raise; anything else is
# named by its CiA 301 class (canopen.emcy.EmcyError.get_desc).
EMCY_NAMES: dict[int, str] = {
    0x2310: "continuous over-current",
    0x3210: "DC link over-voltage",
    0x3220: "DC link under-voltage",
    0x4310: "drive over-temperature",
    0x5530: "EEPROM fault",
    0x7305: "incremental encoder fault",
    0x8130: "heartbeat or life guard error",
    0x8611: "following error",
    0x8700: "SYNC controller error",
    0xFF00: "manufacturer-specific fault",
}


# -- what goes over the bus --------------------------------------------------------------------

HEARTBEAT_COB_BASE = 0x700
"""Heartbeat (and boot-up) of node n: COB-ID 0x700 + n (CiA 301)."""
EMCY_COB_BASE = 0x080
"""EMCY of node n: COB-ID 0x080 + n (CiA 301, predefined connection set)."""
NMT_COB_ID = 0x000
TPDO_COB_BASE = (0x180, 0x280, 0x380, 0x480)
"""TPDO 1-4 of node n: base + n (CiA 301, predefined connection set). The driver keeps the
COB-ID a drive reports for each TPDO it maps (``bringup.map_pdos``), which on a drive in its
predefined connection set, as shipped and as the emulator's, is this."""


class NmtCommand(IntEnum):
    """Byte 0 of an NMT node-control frame (COB-ID 0x000; byte 1: node id, 0 for all)."""

    START = 0x01
    STOP = 0x02
    ENTER_PRE_OPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82


PDO_FORMATS: dict[Index, str] = {
    Index.CONTROLWORD: "H", Index.TARGET_POSITION: "i", Index.MODES_OF_OPERATION: "b",
    Index.STATUSWORD: "H", Index.POSITION_ACTUAL: "i", Index.TORQUE_ACTUAL: "h",
    Index.VELOCITY_ACTUAL: "i", Index.MODES_DISPLAY: "b",
}
"""``struct`` code of each object the driver maps, from its EDS data type (UNSIGNED16,
INTEGER32, INTEGER8, INTEGER16); PDO data is little-endian (CiA 301)."""
OBJECT_BYTES = {index: struct.calcsize(code) for index, code in PDO_FORMATS.items()}

RPDO_LAYOUT = ((Index.CONTROLWORD, Index.TARGET_POSITION, Index.MODES_OF_OPERATION),)
TPDO_LAYOUT = (
    (Index.STATUSWORD, Index.POSITION_ACTUAL, Index.TORQUE_ACTUAL),
    (Index.VELOCITY_ACTUAL, Index.MODES_DISPLAY),
)
"""The PDOs the driver maps on every drive at configure (``bringup.map_pdos``): RPDO1, and
TPDO1 and TPDO2, all synchronous. Whoever reads a drive's TPDOs (the safety monitor's listener)
decodes them with this layout."""


def pdo_struct(layout: tuple[Index, ...]) -> struct.Struct:
    """The encoding of one PDO with this layout, objects packed in order."""
    return struct.Struct("<" + "".join(PDO_FORMATS[index] for index in layout))
