"""CiA 301 / CiA 402 as the emulated drive implements them: object indices, the bits of the
controlword and the statusword, power states, modes of operation.

Written from the specifications (CiA 301 §7.5, CiA 402-2 §6-§8), not taken from the driver in
``drivers/canopen402``: an emulator that shared the driver's tables would agree with any mistake
in them. tests/drivers/test_canopen402_tables.py checks both sides against canopen's own
``State402`` tables.
"""

from __future__ import annotations

from enum import IntEnum, StrEnum


class Index(IntEnum):
    """Objects of the dictionary the drive serves (``dictionary.py`` builds it)."""

    DEVICE_TYPE = 0x1000
    ERROR_REGISTER = 0x1001
    COB_ID_SYNC = 0x1005
    COMM_CYCLE_PERIOD = 0x1006
    """SYNC interval in microseconds: the emulator steps its plant by it."""
    HEARTBEAT_CONSUMER = 0x1016
    """Consumer heartbeat time: per sub-index, the node id it watches (bits 16-23) and how long
    that node's heartbeat may stay away, in ms (bits 0-15); 0 in either: not used."""
    HEARTBEAT_TIME = 0x1017
    IDENTITY = 0x1018
    RPDO_COMMUNICATION = 0x1400
    RPDO_MAPPING = 0x1600
    TPDO_COMMUNICATION = 0x1800
    TPDO_MAPPING = 0x1A00
    ABORT_CONNECTION_OPTION = 0x6007
    """What the drive does when its connection to the master is lost (``AbortConnection``)."""
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
    """In position units per second; written at power-on from the drive's build, not enforced
    by this emulator (a CSP target stream is followed as it comes)."""
    POSITION_ENCODER_RESOLUTION = 0x608F
    """Sub 1 encoder increments per sub 2 motor revolutions."""
    GEAR_RATIO = 0x6091
    """Sub 1 motor revolutions per sub 2 shaft (joint) revolutions."""
    INTERPOLATION_PERIOD = 0x60C2
    SUPPORTED_MODES = 0x6502


PDO_CHANNELS = 4
"""RPDOs and TPDOs the drive offers (CiA 301 predefined connection set: four each)."""
SYNC_COB_ID = 0x80
NMT_COB_ID = 0x000


class Mode(IntEnum):
    """Modes of operation (0x6060/0x6061) the drive knows; it implements only CSP."""

    NO_MODE = 0
    CYCLIC_SYNCHRONOUS_POSITION = 8


SUPPORTED_MODE_BITS = {Mode.CYCLIC_SYNCHRONOUS_POSITION: 1 << 7}
"""0x6502 has one bit per mode; CSP is bit 7 (CiA 402-2, 0x6502)."""


class AbortConnection(IntEnum):
    """0x6007 values (CiA 402-2): the drive's reaction to a lost connection (bus-off, heartbeat
    or life guarding event, NMT STOPPED, reset application, reset communication). Negative
    values are manufacturer-specific; this drive has none."""

    NO_ACTION = 0
    FAULT_SIGNAL = 1
    """Into FAULT through FAULT REACTION ACTIVE, as any drive fault."""
    DISABLE_VOLTAGE = 2
    """The disable voltage command: power stage off, SWITCH ON DISABLED."""
    QUICK_STOP = 3
    """The quick stop command: down the quick-stop ramp, then as 0x605A says."""


class ControlBit(IntEnum):
    """Controlword (0x6040) bits of device control (CiA 402-2, 6.2.1).

    IntEnum, not IntFlag: ``word & bit`` stays a plain int (IntFlag arithmetic costs a
    microsecond per operation, on the path of every RPDO and TPDO)."""

    SWITCH_ON = 1 << 0
    ENABLE_VOLTAGE = 1 << 1
    QUICK_STOP = 1 << 2
    """Active low: a controlword with this bit cleared asks for a quick stop."""
    ENABLE_OPERATION = 1 << 3
    FAULT_RESET = 1 << 7
    """A fault reset happens on its rising edge."""


class StatusBit(IntEnum):
    """Statusword (0x6041) bits (CiA 402-2, 6.2.2)."""

    READY_TO_SWITCH_ON = 1 << 0
    SWITCHED_ON = 1 << 1
    OPERATION_ENABLED = 1 << 2
    FAULT = 1 << 3
    VOLTAGE_ENABLED = 1 << 4
    QUICK_STOP = 1 << 5
    """Active low: cleared while a quick stop is active."""
    SWITCH_ON_DISABLED = 1 << 6
    WARNING = 1 << 7
    REMOTE = 1 << 9
    TARGET_REACHED = 1 << 10
    FOLLOWS_COMMAND = 1 << 12
    """In CSP: the drive follows the target position it receives."""
    FOLLOWING_ERROR = 1 << 13


class PowerState(StrEnum):
    """The power drive system states of CiA 402-2 (figure 12), named as the standard does."""

    NOT_READY_TO_SWITCH_ON = "NOT READY TO SWITCH ON"
    SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
    READY_TO_SWITCH_ON = "READY TO SWITCH ON"
    SWITCHED_ON = "SWITCHED ON"
    OPERATION_ENABLED = "OPERATION ENABLED"
    QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
    FAULT_REACTION_ACTIVE = "FAULT REACTION ACTIVE"
    FAULT = "FAULT"


_S = StatusBit
_POWERED = _S.READY_TO_SWITCH_ON | _S.SWITCHED_ON | _S.VOLTAGE_ENABLED
STATE_STATUS: dict[PowerState, int] = {
    PowerState.NOT_READY_TO_SWITCH_ON: 0,
    PowerState.SWITCH_ON_DISABLED: _S.SWITCH_ON_DISABLED,
    PowerState.READY_TO_SWITCH_ON: _S.QUICK_STOP | _S.READY_TO_SWITCH_ON,
    PowerState.SWITCHED_ON: _S.QUICK_STOP | _POWERED,
    PowerState.OPERATION_ENABLED: _S.QUICK_STOP | _POWERED | _S.OPERATION_ENABLED,
    PowerState.QUICK_STOP_ACTIVE: _POWERED | _S.OPERATION_ENABLED,
    PowerState.FAULT_REACTION_ACTIVE: (_S.FAULT | _S.OPERATION_ENABLED | _S.SWITCHED_ON
                                       | _S.READY_TO_SWITCH_ON),
    PowerState.FAULT: _S.FAULT,
}
"""Statusword state bits the drive reports in each state (CiA 402-2, table 30; bit 4, voltage
enabled, is set where the power stage is on)."""


class DeviceCommand(StrEnum):
    """Device-control commands a controlword carries (CiA 402-2, table 31); a fault reset is
    the rising edge of its own bit (``ControlBit.FAULT_RESET``)."""

    SHUTDOWN = "shutdown"
    SWITCH_ON = "switch on"
    ENABLE_OPERATION = "enable operation"
    DISABLE_VOLTAGE = "disable voltage"
    QUICK_STOP = "quick stop"


DEVICE_TYPE_SERVO = 0x0002_0192
"""0x1000: device profile 402 (low word) with the servo drive type (bits 16-23 = 0x02)."""
ERROR_REGISTER_GENERIC = 1 << 0
ERROR_REGISTER_CURRENT = 1 << 1
ERROR_REGISTER_COMMUNICATION = 1 << 4
ERROR_REGISTER_PROFILE = 1 << 5
NO_FOLLOWING_LIMIT = 0xFFFF_FFFF
"""0x6065 = all ones: following-error supervision off."""
ABORT_VALUE_RANGE = 0x0609_0030
"""SDO abort code: value range of parameter exceeded (CiA 301, table 22)."""
EMCY_FOLLOWING_ERROR = 0x8611
EMCY_HEARTBEAT = 0x8130
"""Life guard error or heartbeat error (CiA 301, table 21)."""
EMCY_COMMUNICATION = 0x8100
"""Communication, generic (CiA 301, table 21)."""
EMCY_OVER_CURRENT = 0x2310
