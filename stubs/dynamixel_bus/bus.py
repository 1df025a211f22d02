"""The servos on one bus: instruction handling, status packets, and the injectable faults.

Replies follow the e-Manual: a unicast instruction gets one status packet; sync read gets one
status packet per listed servo, in the listed order; fast sync read gets one combined packet from
the broadcast id; broadcast ping gets one per servo; sync write and other broadcasts get none.
Each status packet carries the alert bit while its servo has a hardware error. Every good
instruction packet feeds the Bus Watchdog of the servos it addresses; ``check_watchdogs`` stops
the servos whose watchdog expired (:mod:`stubs.dynamixel_bus.watchdog`).
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from stubs.dynamixel_bus.control_table import Addr, HardwareError, ServoTable
from stubs.dynamixel_bus.crc import crc16
from stubs.dynamixel_bus.packet import (
    BROADCAST_ID,
    HEADER,
    ErrorCode,
    Frame,
    Instruction,
    encode_status,
)
from stubs.dynamixel_bus.plant_link import PlantLink
from stubs.dynamixel_bus.watchdog import BusWatchdogClock

Handler = Callable[[Frame], bytes]


@dataclass(slots=True)
class BusFaults:
    silent: set[int] = field(default_factory=set)
    """Servos that no longer answer anything (cable cut, brown-out)."""
    corrupt_remaining: int = 0
    """How many of the next status packets leave with a wrong CRC."""


class Bus:
    def __init__(
        self, servos: dict[int, ServoTable], link: PlantLink, *, fast_sync_read: bool = True
    ) -> None:
        self.servos = servos
        self.link = link
        self.faults = BusFaults()
        self.lock = threading.Lock()
        self.watchdog = BusWatchdogClock(servos, time.monotonic())
        self._handlers: dict[int, Handler] = {
            Instruction.PING: self._ping,
            Instruction.READ: self._read,
            Instruction.WRITE: self._write,
            Instruction.SYNC_READ: self._sync_read,
            Instruction.SYNC_WRITE: self._sync_write,
        }
        if fast_sync_read:  # older firmware does not know 0x8A and stays silent
            self._handlers[Instruction.FAST_SYNC_READ] = self._fast_sync_read

    def power_on(self) -> None:
        """Goal Position starts at Present Position, so enabling torque moves nothing."""
        with self.lock:
            self._settle_goals()

    def handle(self, frame: Frame) -> bytes:
        """The bytes the bus sends back for one instruction packet (often none)."""
        with self.lock:
            if not frame.crc_ok:
                return self._unicast_error(frame, ErrorCode.CRC)
            self.watchdog.heard(self._hearing(frame.servo_id), time.monotonic())
            handler = self._handlers.get(frame.instruction)
            if handler is None:
                return self._unicast_error(frame, ErrorCode.INSTRUCTION)
            return handler(frame)

    # ------------------------------------------------------------------ bus watchdog

    def next_watchdog_deadline(self) -> float | None:
        """time.monotonic() at which the first armed Bus Watchdog expires, or None."""
        with self.lock:
            return self.watchdog.deadline(self.servos)

    def check_watchdogs(self, now: float) -> list[int]:
        """Stop every servo whose Bus Watchdog expired by ``now``; returns their ids."""
        with self.lock:
            expired = self.watchdog.expired(self.servos, now)
            if expired:
                self.link.refresh(self.servos, reported=False)  # they stop where they are
                for servo_id in expired:
                    self.servos[servo_id].trip_watchdog()
                self.link.halt(self.servos)
        if expired:
            print(f"dynamixel_bus: Bus Watchdog expired on ids {expired}: stopped",
                  file=sys.stderr)
        return expired

    def _hearing(self, servo_id: int) -> list[int]:
        ids = self.servos if servo_id == BROADCAST_ID else [servo_id]
        return [i for i in ids if i in self.servos and i not in self.faults.silent]

    # ------------------------------------------------------------------ instructions

    def _ping(self, frame: Frame) -> bytes:
        ids = sorted(self.servos) if frame.servo_id == BROADCAST_ID else [frame.servo_id]
        return b"".join(self._status(servo_id, ErrorCode.NONE, self._identity(servo_id))
                        for servo_id in ids if servo_id in self.servos)

    def _read(self, frame: Frame) -> bytes:
        if frame.servo_id not in self.servos or len(frame.params) != 4:
            return self._unicast_error(frame, ErrorCode.DATA_LENGTH)
        address, length = _u16(frame.params, 0), _u16(frame.params, 2)
        self.link.refresh(self.servos)
        error, data = self.servos[frame.servo_id].read(address, length)
        return self._status(frame.servo_id, error, data)

    def _write(self, frame: Frame) -> bytes:
        if len(frame.params) < 3:
            return self._unicast_error(frame, ErrorCode.DATA_LENGTH)
        address, data = _u16(frame.params, 0), frame.params[2:]
        targets = self.servos if frame.servo_id == BROADCAST_ID else [frame.servo_id]
        errors = {servo_id: self.servos[servo_id].write(address, data)
                  for servo_id in targets
                  if servo_id in self.servos and servo_id not in self.faults.silent}
        self.link.apply(self.servos)
        if frame.servo_id not in errors:
            return b""
        return self._status(frame.servo_id, errors[frame.servo_id])

    def _sync_write(self, frame: Frame) -> bytes:
        address, length = _u16(frame.params, 0), _u16(frame.params, 2)
        block = 1 + length
        for start in range(4, len(frame.params) - block + 1, block):
            servo_id = frame.params[start]
            if servo_id in self.servos and servo_id not in self.faults.silent:
                self.servos[servo_id].write(address, frame.params[start + 1:start + block])
        self.link.apply(self.servos)
        return b""  # sync write is never answered

    def _sync_read(self, frame: Frame) -> bytes:
        address, length, ids = _u16(frame.params, 0), _u16(frame.params, 2), frame.params[4:]
        self.link.refresh(self.servos)
        replies = []
        for servo_id in self._answering_chain(ids):
            error, data = self.servos[servo_id].read(address, length)
            replies.append(self._status(servo_id, error, data))
        return b"".join(replies)

    def _fast_sync_read(self, frame: Frame) -> bytes:
        address, length, ids = _u16(frame.params, 0), _u16(frame.params, 2), frame.params[4:]
        self.link.refresh(self.servos)
        chain = self._answering_chain(ids)
        if not chain:
            return b""
        packet = bytearray(HEADER + bytes([BROADCAST_ID]))
        packet += (1 + len(ids) * (length + 4)).to_bytes(2, "little")
        packet.append(Instruction.STATUS)
        crc = crc16(packet)  # carried along: each servo sums what went over the wire so far
        for servo_id in chain:
            servo = self.servos[servo_id]
            error, data = servo.read(address, length)
            section = bytes([error | servo.alert(), servo_id]) + data.ljust(length, b"\0")
            crc = crc16(section, crc)
            packet += section + crc.to_bytes(2, "little")
            crc = crc16(crc.to_bytes(2, "little"), crc)
        # A silent servo breaks the chain: the servos after it never get their turn, and the
        # host sees a packet shorter than its length field (COMM_RX_CORRUPT after the timeout).
        return self._corrupt_if_due(bytes(packet))

    # ------------------------------------------------------------------ status packets

    def _answering_chain(self, ids: Iterable[int]) -> list[int]:
        """The listed servos that reply, in order, up to the first one that cannot."""
        chain = []
        for servo_id in ids:
            if servo_id not in self.servos or servo_id in self.faults.silent:
                break
            chain.append(servo_id)
        return chain

    def _status(self, servo_id: int, error: int, params: bytes = b"") -> bytes:
        if servo_id in self.faults.silent:
            return b""
        packet = encode_status(servo_id, error | self.servos[servo_id].alert(), params)
        return self._corrupt_if_due(packet)

    def _unicast_error(self, frame: Frame, error: ErrorCode) -> bytes:
        if frame.servo_id not in self.servos:
            return b""  # broadcast or nobody by that id: nobody answers
        return self._status(frame.servo_id, error)

    def _corrupt_if_due(self, packet: bytes) -> bytes:
        if self.faults.corrupt_remaining <= 0 or len(packet) < 2:
            return packet
        self.faults.corrupt_remaining -= 1
        return packet[:-2] + bytes([packet[-2] ^ 0xFF, packet[-1] ^ 0xFF])

    def _identity(self, servo_id: int) -> bytes:
        servo = self.servos[servo_id]
        model = servo.get(Addr.MODEL_NUMBER, 2)
        return model.to_bytes(2, "little") + bytes([servo.get(Addr.FIRMWARE_VERSION, 1)])

    # ------------------------------------------------------------------ fault injection

    def fault_handlers(self) -> dict[str, Callable[[dict[str, Any]], None]]:
        return {
            "silent": self._inject_silent,
            "crc": self._inject_crc,
            "hardware_error": self._inject_hardware_error,
            "reading_glitch": self.link.glitch.start,
            "clear": self._clear,
            "peek": self._peek,
            "motion": self._motion,
        }

    def _motion(self, request: dict[str, Any]) -> dict[str, Any]:
        """Not a fault: the goal writes each servo applied with torque on (tests)."""
        with self.lock:
            by_id = {str(i): servo.motion_writes for i, servo in self.servos.items()}
        return {"motion_commands": sum(by_id.values()), "by_id": by_id}

    def _peek(self, request: dict[str, Any]) -> dict[str, Any]:
        """Not a fault: one control-table item (``item``: its address, ``size`` in bytes) as
        the servo holds it, signed (tests, no bus needed)."""
        address, size = int(request["item"]), int(request.get("size", 1))
        with self.lock:
            value = self.servos[self._known_id(request)].get(address, size, signed=True)
        return {"value": value}

    def _inject_silent(self, request: dict[str, Any]) -> None:
        with self.lock:
            self.faults.silent.add(self._known_id(request))

    def _inject_crc(self, request: dict[str, Any]) -> None:
        with self.lock:
            self.faults.corrupt_remaining = int(request.get("count", 1))

    def _inject_hardware_error(self, request: dict[str, Any]) -> None:
        bit = HardwareError[str(request.get("bit", "overload")).upper()]
        with self.lock:
            self.servos[self._known_id(request)].trip(bit)
            self.link.apply(self.servos)

    def _clear(self, request: dict[str, Any]) -> None:
        """Undo every fault, as a power cycle would: errors cleared, torque off, Bus Watchdog
        off (RAM items restart at their defaults)."""
        self.link.glitch.clear()
        with self.lock:
            self.faults = BusFaults()
            for servo in self.servos.values():
                servo.clear_error()
                servo.set(Addr.TORQUE_ENABLE, 1, 0)
                servo.set(Addr.BUS_WATCHDOG, 1, 0)
            self._settle_goals()
            self.link.apply(self.servos)

    def _settle_goals(self) -> None:
        self.link.refresh(self.servos, reported=False)
        for servo in self.servos.values():
            present = servo.get(Addr.PRESENT_POSITION, 4, signed=True)
            servo.set(Addr.GOAL_POSITION, 4, present)

    def _known_id(self, request: dict[str, Any]) -> int:
        servo_id = int(request["id"])
        if servo_id not in self.servos:
            raise ValueError(f"no servo with id {servo_id} on this bus")
        return servo_id


def _u16(data: bytes, offset: int) -> int:
    return int.from_bytes(data[offset:offset + 2], "little")
