"""The control table of one emulated X-series servo (XM430-W350 by default), from the e-Manual.

Only what a driver can observe is modelled: item addresses and sizes, which items are read-only,
that the EEPROM area (addresses below 64) refuses writes while torque is on, that Goal Position
must lie within the position limits, that a hardware error switches torque off, and the Bus
Watchdog (98): 0 off (writing 0 also clears its error), 1..127 armed in 20 ms units, -1 after it
expired, when the goal values (Goal PWM, Current, Velocity, Position) refuse writes with a Data
Range Error until 0 is written (:mod:`stubs.dynamixel_bus.watchdog` times it).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, IntFlag

from stubs.dynamixel_bus.packet import ErrorCode

EEPROM_END = 64
"""Addresses below this are EEPROM: writable only while Torque Enable is 0."""
TABLE_SIZE = 228


@dataclass(frozen=True, slots=True)
class Item:
    address: int
    size: int
    writable: bool
    default: int = 0


class Addr(IntEnum):
    """Addresses the emulator's own logic refers to (every item is in :data:`ITEMS`)."""

    MODEL_NUMBER = 0
    FIRMWARE_VERSION = 6
    ID = 7
    BAUD_RATE = 8
    OPERATING_MODE = 11
    CURRENT_LIMIT = 38
    SHUTDOWN = 63
    MAX_POSITION_LIMIT = 48
    MIN_POSITION_LIMIT = 52
    TORQUE_ENABLE = 64
    HARDWARE_ERROR_STATUS = 70
    BUS_WATCHDOG = 98
    GOAL_PWM = 100
    GOAL_CURRENT = 102
    GOAL_VELOCITY = 104
    PROFILE_ACCELERATION = 108
    GOAL_POSITION = 116
    MOVING = 122
    PRESENT_CURRENT = 126
    PRESENT_VELOCITY = 128
    PRESENT_POSITION = 132


ITEMS: tuple[Item, ...] = (
    Item(0, 2, False, 1020),  # Model Number (XM430-W350)
    Item(2, 4, False),  # Model Information
    Item(6, 1, False, 52),  # Firmware Version
    Item(7, 1, True, 1),  # ID
    Item(8, 1, True, 3),  # Baud Rate (3 = 1 Mbps)
    Item(9, 1, True, 250),  # Return Delay Time (2 us units)
    Item(10, 1, True),  # Drive Mode
    Item(11, 1, True, 3),  # Operating Mode (3 = position)
    Item(12, 1, True, 255),  # Secondary ID
    Item(13, 1, True, 2),  # Protocol Type
    Item(20, 4, True),  # Homing Offset
    Item(24, 4, True, 10),  # Moving Threshold
    Item(31, 1, True, 80),  # Temperature Limit
    Item(32, 2, True, 160),  # Max Voltage Limit
    Item(34, 2, True, 95),  # Min Voltage Limit
    Item(36, 2, True, 885),  # PWM Limit
    Item(38, 2, True, 1193),  # Current Limit
    Item(44, 4, True, 200),  # Velocity Limit
    Item(48, 4, True, 4095),  # Max Position Limit
    Item(52, 4, True, 0),  # Min Position Limit
    Item(63, 1, True, 0x34),  # Shutdown: overheating, electrical shock, overload
    Item(64, 1, True),  # Torque Enable
    Item(65, 1, True),  # LED
    Item(68, 1, True, 2),  # Status Return Level
    Item(69, 1, False),  # Registered Instruction
    Item(70, 1, False),  # Hardware Error Status
    Item(76, 2, True, 100),  # Velocity I Gain
    Item(78, 2, True, 1920),  # Velocity P Gain
    Item(80, 2, True),  # Position D Gain
    Item(82, 2, True),  # Position I Gain
    Item(84, 2, True, 800),  # Position P Gain
    Item(98, 1, True),  # Bus Watchdog (20 ms units, signed: -1 is Bus Watchdog Error)
    Item(100, 2, True),  # Goal PWM
    Item(102, 2, True),  # Goal Current
    Item(104, 4, True),  # Goal Velocity
    Item(108, 4, True),  # Profile Acceleration
    Item(112, 4, True),  # Profile Velocity
    Item(116, 4, True, 2048),  # Goal Position
    Item(120, 2, False),  # Realtime Tick
    Item(122, 1, False),  # Moving
    Item(123, 1, False),  # Moving Status
    Item(124, 2, False),  # Present PWM
    Item(126, 2, False),  # Present Current
    Item(128, 4, False),  # Present Velocity
    Item(132, 4, False, 2048),  # Present Position
    Item(136, 4, False),  # Velocity Trajectory
    Item(140, 4, False),  # Position Trajectory
    Item(144, 2, False, 120),  # Present Input Voltage (0.1 V)
    Item(146, 1, False, 36),  # Present Temperature (deg C)
)


class HardwareError(IntFlag):
    """Bits of Hardware Error Status (70)."""

    INPUT_VOLTAGE = 0x01
    OVERHEATING = 0x04
    MOTOR_ENCODER = 0x08
    ELECTRICAL_SHOCK = 0x10
    OVERLOAD = 0x20


OPERATING_MODES = frozenset({0, 1, 3, 4, 5, 16})
BUS_WATCHDOG_MAX_UNITS = 127
BUS_WATCHDOG_ERROR = -1
GOAL_VALUES = ((Addr.GOAL_PWM, Addr.PROFILE_ACCELERATION), (Addr.GOAL_POSITION, 120))
"""Byte ranges of Goal PWM, Current and Velocity (100-107) and Goal Position (116-119): read-only
while the Bus Watchdog is in error (the profile items between them are not goal values)."""


def _writable_map() -> bytes:
    writable = bytearray(TABLE_SIZE)
    for item in ITEMS:
        if item.writable:
            writable[item.address:item.address + item.size] = b"\x01" * item.size
    return bytes(writable)


_WRITABLE = _writable_map()


class ServoTable:
    """The bytes of one servo's control table, with the access rules of the firmware."""

    def __init__(self, servo_id: int, model_number: int = 1020, baud_code: int = 3) -> None:
        self.memory = bytearray(TABLE_SIZE)
        for item in ITEMS:
            self.set(item.address, item.size, item.default)
        self.set(Addr.MODEL_NUMBER, 2, model_number)
        self.set(Addr.ID, 1, servo_id)
        self.set(Addr.BAUD_RATE, 1, baud_code)
        self.motion_writes = 0
        """Writes of a goal value (Goal PWM, Current, Velocity, Position) applied while torque
        was on: each one can move the servo, even a goal equal to where it already is."""

    def get(self, address: int, size: int, signed: bool = False) -> int:
        raw = self.memory[address:address + size]
        return int.from_bytes(raw, "little", signed=signed)

    def set(self, address: int, size: int, value: int) -> None:
        self.memory[address:address + size] = (value % (1 << (8 * size))).to_bytes(size, "little")

    @property
    def torque_enabled(self) -> bool:
        return self.memory[Addr.TORQUE_ENABLE] == 1

    @property
    def hardware_error(self) -> int:
        return self.memory[Addr.HARDWARE_ERROR_STATUS]

    @property
    def bus_watchdog(self) -> int:
        """Bus Watchdog (98): 0 off, 1..127 armed (20 ms units), -1 expired."""
        return self.get(Addr.BUS_WATCHDOG, 1, signed=True)

    @property
    def watchdog_error(self) -> bool:
        return self.bus_watchdog == BUS_WATCHDOG_ERROR

    def trip_watchdog(self) -> None:
        """The Bus Watchdog expired: the servo stops where it is (call with Present Position
        fresh). The manual says it stops and its goal values turn read-only; that Goal Position
        then reads the stop position is this emulator's choice (the manual does not say)."""
        self.set(Addr.BUS_WATCHDOG, 1, BUS_WATCHDOG_ERROR)
        self.set(Addr.GOAL_POSITION, 4, self.get(Addr.PRESENT_POSITION, 4, signed=True))
        self.set(Addr.GOAL_VELOCITY, 4, 0)

    def alert(self) -> int:
        """The error-byte alert bit this servo puts in every status packet."""
        return 0x80 if self.hardware_error else 0

    def read(self, address: int, length: int) -> tuple[int, bytes]:
        if length == 0 or address + length > TABLE_SIZE:
            return ErrorCode.DATA_LENGTH, b""
        return ErrorCode.NONE, bytes(self.memory[address:address + length])

    def write(self, address: int, data: bytes) -> int:
        """Apply a write as the firmware would; returns the error code (0 when applied)."""
        error = self._check_write(address, data)
        if error == ErrorCode.NONE:
            self.memory[address:address + len(data)] = data
            end = address + len(data)
            if self.torque_enabled and any(_overlaps(address, end, low, high)
                                           for low, high in GOAL_VALUES):
                self.motion_writes += 1
        return error

    def trip(self, bits: int) -> None:
        """Latch a hardware error; the bits named in Shutdown (63) switch torque off."""
        self.memory[Addr.HARDWARE_ERROR_STATUS] |= bits
        if bits & self.memory[Addr.SHUTDOWN]:
            self.memory[Addr.TORQUE_ENABLE] = 0

    def clear_error(self) -> None:
        self.memory[Addr.HARDWARE_ERROR_STATUS] = 0

    def _check_write(self, address: int, data: bytes) -> int:
        end = address + len(data)
        if not data or end > TABLE_SIZE:
            return ErrorCode.DATA_LENGTH
        if not all(_WRITABLE[address:end]):
            return ErrorCode.ACCESS
        if address < EEPROM_END and self.torque_enabled:
            return ErrorCode.ACCESS  # EEPROM is locked while torque is on
        if self.watchdog_error and any(_overlaps(address, end, low, high)
                                       for low, high in GOAL_VALUES):
            return ErrorCode.DATA_RANGE  # goal values are read-only until 98 is cleared
        if self.hardware_error and _touches(address, end, Addr.TORQUE_ENABLE, 1) and data[
            Addr.TORQUE_ENABLE - address
        ]:
            return ErrorCode.RESULT_FAIL  # torque stays off until the error is cleared
        return self._check_values(address, data)

    def _check_values(self, address: int, data: bytes) -> int:
        mode_written = _touches(address, address + len(data), Addr.OPERATING_MODE, 1)
        if mode_written and data[Addr.OPERATING_MODE - address] not in OPERATING_MODES:
            return ErrorCode.DATA_RANGE
        if _touches(address, address + len(data), Addr.BUS_WATCHDOG, 1):
            units = int.from_bytes(data[Addr.BUS_WATCHDOG - address:][:1], "little", signed=True)
            # In error only 0 (clear) is taken: the manual names no other way out of it.
            if not 0 <= units <= BUS_WATCHDOG_MAX_UNITS or (self.watchdog_error and units):
                return ErrorCode.DATA_RANGE
        if _touches(address, address + len(data), Addr.GOAL_CURRENT, 2):
            offset = Addr.GOAL_CURRENT - address
            goal = int.from_bytes(data[offset:offset + 2], "little", signed=True)
            if abs(goal) > self.get(Addr.CURRENT_LIMIT, 2):
                return ErrorCode.DATA_LIMIT
        if _touches(address, address + len(data), Addr.GOAL_POSITION, 4):
            offset = Addr.GOAL_POSITION - address
            goal = int.from_bytes(data[offset:offset + 4], "little", signed=True)
            if self._position_limited() and not self._within_limits(goal):
                return ErrorCode.DATA_LIMIT
        return ErrorCode.NONE

    def _position_limited(self) -> bool:
        return self.memory[Addr.OPERATING_MODE] == 3

    def _within_limits(self, goal: int) -> bool:
        low = self.get(Addr.MIN_POSITION_LIMIT, 4)
        high = self.get(Addr.MAX_POSITION_LIMIT, 4)
        return low <= goal <= high


def _touches(start: int, end: int, address: int, size: int) -> bool:
    """Whether the write [start, end) covers the whole item at ``address``."""
    return start <= address and address + size <= end


def _overlaps(start: int, end: int, low: int, high: int) -> bool:
    """Whether the write [start, end) touches any byte of [low, high)."""
    return start < high and low < end
