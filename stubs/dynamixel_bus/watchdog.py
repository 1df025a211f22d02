"""When each servo last heard an instruction packet, and whose Bus Watchdog (98) has expired.

Robotis e-Manual, X-series "Bus Watchdog(98)": a fail-safe that stops the servo when the
communication with the controller is interrupted; "the communication is defined as all the
Instruction Packet in the DYNAMIXEL Protocol". It monitors the interval between packets while
Torque Enable is 1; an interval longer than the set value (units of 20 ms) stops the servo and
sets 98 to -1. Here a servo hears a packet with a good CRC addressed to its id or to the
broadcast id (sync and fast sync instructions are broadcasts); a servo cut off the bus (the
``silent`` fault) hears nothing.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from stubs.dynamixel_bus.control_table import BUS_WATCHDOG_MAX_UNITS, ServoTable

UNIT_S = 0.020
"""One Bus Watchdog unit."""


class BusWatchdogClock:
    def __init__(self, ids: Iterable[int], now: float) -> None:
        self._heard = dict.fromkeys(ids, now)

    def heard(self, ids: Iterable[int], now: float) -> None:
        for servo_id in ids:
            self._heard[servo_id] = now

    def deadline(self, servos: Mapping[int, ServoTable]) -> float | None:
        """The earliest instant at which an armed servo's watchdog expires, or None."""
        deadlines = [self._heard[i] + s.bus_watchdog * UNIT_S
                     for i, s in servos.items() if _armed(s)]
        return min(deadlines, default=None)

    def expired(self, servos: Mapping[int, ServoTable], now: float) -> list[int]:
        """The armed servos that have heard nothing for longer than their watchdog time."""
        return [i for i, s in servos.items()
                if _armed(s) and now - self._heard[i] > s.bus_watchdog * UNIT_S]


def _armed(servo: ServoTable) -> bool:
    return servo.torque_enabled and 1 <= servo.bus_watchdog <= BUS_WATCHDOG_MAX_UNITS
