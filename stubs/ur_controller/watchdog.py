"""The controller's RTDE input watchdogs: URScript ``rtde_set_watchdog`` as the controller runs it.

URScript manual: ``rtde_set_watchdog(variable_name, min_frequency, action="pause")`` watches one
RTDE input variable; "when the watchdog did not receive an input update for the specified
variable in the time period specified by min_frequency (Hz), the corresponding action will be
taken" ("ignore", "pause" or "stop" the program), and "all watchdogs are removed on program
stop". ur_rtde 1.6.5's ``setWatchdog`` is command 35 of its ``rtde_control`` script, which calls
``rtde_set_watchdog("input_int_register_0", min_frequency, "stop")`` (register 24 with the upper
register range), so "stop" is the only action emulated.

An update is any input data package whose recipe carries the variable, whatever its value:
every command ur_rtde sends carries ``input_int_register_0`` (servoJ and speedJ carry their
command id, the clear command and ``kickWatchdog`` a 0). Time is counted in controller cycles,
as the controller's real-time loop counts it: an emulator process the host deschedules for a
while runs fewer cycles, and does not see a silence the client never caused.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(slots=True)
class InputWatchdog:
    variable: str
    min_frequency_hz: float
    silent_cycles: int = 0
    """Controller cycles since the last input package that carried ``variable``."""


class RTDEWatchdogs:
    """Every armed watchdog, checked once per controller cycle (call under the controller lock)."""

    def __init__(self, cycle_s: float) -> None:
        self.cycle_s = cycle_s
        self._armed: dict[str, InputWatchdog] = {}
        self.fired = 0
        """How many times a watchdog stopped the program since the controller started."""

    def arm(self, variable: str, min_frequency_hz: float) -> None:
        """``rtde_set_watchdog(variable, min_frequency_hz, "stop")``: one per variable; arming
        it again replaces it and restarts its count."""
        self._armed[variable] = InputWatchdog(variable, min_frequency_hz)

    def clear(self) -> None:
        """The program stopped: its watchdogs go with it."""
        self._armed.clear()

    def saw(self, names: list[str]) -> None:
        """An input package with these variables was applied."""
        for name in names:
            watchdog = self._armed.get(name)
            if watchdog is not None:
                watchdog.silent_cycles = 0

    def expired(self) -> InputWatchdog | None:
        """One controller cycle passed: the first watchdog whose silence is now longer than
        1 / min_frequency, or None."""
        for watchdog in self._armed.values():
            watchdog.silent_cycles += 1
        for watchdog in self._armed.values():
            if watchdog.silent_cycles * self.cycle_s * watchdog.min_frequency_hz > 1.0:
                return watchdog
        return None

    def snapshot(self) -> dict[str, object]:
        """What a test may ask over the control port (the controller has no RTDE output for it)."""
        return {"armed": {w.variable: w.min_frequency_hz for w in self._armed.values()},
                "fired": self.fired}
