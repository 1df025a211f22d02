"""The controller side of ur_rtde's uploaded ``rtde_control`` URScript program.

ur_rtde 1.6.5 uploads a ~42 KB program to port 30003 and then talks to it only through RTDE
registers. We do not interpret URScript; we run the same state machine that program runs
(its "Main loop" and ``process_cmd``), once per controller cycle, exactly like its ``sync()``:

- ``output_int_register_0`` = 1 "ready", 2 "done with command";
- ``input_int_register_0`` = the command id; 0 means "idle, ready for the next one";
- real-time commands (servoJ 11, speedJ 9, ...) are processed every cycle and answer "ready";
- every other command is processed once, answers "done", and waits for the client to write 0;
- ``setWatchdog`` (35) arms the controller's RTDE watchdog on the command register with action
  "stop" (:mod:`stubs.ur_controller.watchdog`); stopping the program removes it;
- the dashboard's ``stop`` ends the program through STOPPING while the arm decelerates
  (:mod:`stubs.ur_controller.program_stop`); the other stops (stop script, an RTDE watchdog, a
  safety stop) still hold the arm at once.

Registers are offset by 24 when the client asked for the upper range; the offset is read from
the uploaded program text, where ur_rtde injects it.
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass

from stubs.plant.base import Plant
from stubs.ur_controller.program_stop import ProgramStop
from stubs.ur_controller.status import ControllerStatus, RegisterBank, RuntimeState
from stubs.ur_controller.watchdog import RTDEWatchdogs

# The command ids of rtde_control.script (ur_rtde 1.6.5, "RTDE Control Script Loaded
# (14.02.2024-12:23)").
MOVEJ, SPEEDJ, SERVOJ = 1, 9, 11
SPEED_STOP, SERVO_STOP, STOPL, STOPJ, SET_WATCHDOG, STOP_SCRIPT = 15, 16, 33, 34, 35, 255
REALTIME_COMMANDS = frozenset({24, 11, 9, 10, 6, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71})
MOTION_COMMANDS = frozenset({
    1, 2, 3, 4,  # moveJ, moveJ_IK, moveL, moveL_FK
    6, 9, 10, 11, 12, 24,  # forceMode, speedJ, speedL, servoJ, servoC, servoL
    18, 41, 45, 51, 52, 66,  # teachMode, jogStart, movePath, moveUntilContact, freedrive, torque
})
"""Every command of rtde_control.script that can set the arm in motion; the stops (speedStop,
servoStop, stopL, stopJ) only bring it to rest, and are counted apart."""
STOP_COMMANDS = frozenset({SPEED_STOP, SERVO_STOP, STOPL, STOPJ})
READY, DONE = 1, 2
ARRIVED_RAD = 1e-3

_OFFSET = re.compile(r"reg_offset_(int|float)\s*=\s*(?:#[^\n]*\n)?\s*(\d+)")


@dataclass(frozen=True, slots=True)
class Offsets:
    int_offset: int = 0
    float_offset: int = 0


def parse_offsets(program: str) -> Offsets:
    """The register offsets ur_rtde injected into the program (0, or 24 for the upper range)."""
    found = {kind: int(value) for kind, value in _OFFSET.findall(program)}
    return Offsets(found.get("int", 0), found.get("float", 0))


class ControlScript:
    """One running instance of ``rtde_control``; ``step`` is one ``sync()`` of its main loop."""

    def __init__(self, status: ControllerStatus, registers: RegisterBank, plant: Plant,
                 cycle_s: float = 0.002, watchdogs: RTDEWatchdogs | None = None) -> None:
        self.status = status
        self.cycle_s = cycle_s
        self.registers = registers
        self.plant = plant
        self.watchdogs = watchdogs or RTDEWatchdogs(cycle_s)
        self.offsets = Offsets()
        self._executing = False
        self._blocking_until: Callable[[], bool] | None = None
        self.servo: dict[str, float] = {}
        """The last servoJ timing parameters (t, lookahead_time, gain), as the script keeps them."""
        self._servo_window: ServoLookahead | None = None
        self._stopping: ProgramStop | None = None
        self.motion_commands = 0
        self.stop_commands = 0
        """Stops the script executed: each is a round trip a client waits for (tests)."""
        """Motion commands executed since the controller started: one per command, and one per
        controller cycle for a real-time one (servoJ, speedJ, ...), which runs every cycle."""
        self._by_command: dict[int, Callable[[], None]] = {
            MOVEJ: self._move_j,
            SPEEDJ: lambda: self.plant.command_velocity(self._doubles(0, 6)),
            SERVOJ: self._servo_j,
            SPEED_STOP: self.plant.hold,
            SERVO_STOP: self.plant.hold,
            STOPL: self.plant.hold,
            STOPJ: self.plant.hold,
            SET_WATCHDOG: self._set_watchdog,
            STOP_SCRIPT: self.stop,
        }

    def load(self, program: str) -> None:
        """A new program replaces the running one and starts PLAYING (as on the controller)."""
        self._end_stopping()  # a new program cuts a deceleration short, holding the arm
        self.offsets = parse_offsets(program)
        self.watchdogs.clear()  # the program it replaces has ended, and its watchdogs with it
        self._servo_window = None
        self._executing = False
        self._blocking_until = None
        self.status.runtime_state = RuntimeState.PLAYING
        self._write_out(2, 1 << 16)  # reset_async_progress(): first write, no operation running
        self._write_out(0, READY)

    def stop(self) -> None:
        """The program ends (stop script, dashboard "stop", a safety stop, an RTDE watchdog).

        The arm stays powered and the safety system is not involved: robot mode RUNNING, safety
        NORMAL, runtime state STOPPED. The plant holds the measured position at once: a real
        controller decelerates along the path instead (not modelled)."""
        self._end_stopping()
        self.status.runtime_state = RuntimeState.STOPPED
        self.watchdogs.clear()
        self._blocking_until = None
        self.plant.hold()

    def stop_decelerating(self) -> ProgramStop | None:
        """The dashboard's ``stop``: STOPPING while the arm decelerates, then STOPPED. Returns
        the stop in progress (its ``done`` is set at rest), or None if no program runs."""
        if self._stopping is not None:
            return self._stopping
        if not self.status.program_running:
            return None
        self.status.runtime_state = RuntimeState.STOPPING
        self.watchdogs.clear()
        self._blocking_until = None
        self._stopping = ProgramStop(self.plant, self.cycle_s)
        return self._stopping

    def step(self) -> None:
        if self._stopping is not None:
            if self._stopping.step():
                self._stopping = None
                self.status.runtime_state = RuntimeState.STOPPED
            return
        if not self.status.program_running:
            return
        if self._blocking_until is not None:
            self._finish_blocking_command()
            return
        command = self.registers.int_in(0, self.offsets.int_offset)
        if command in REALTIME_COMMANDS:
            self._process(command)
            self._write_out(0, READY)
        elif command == 0:
            self._executing = False
            self._write_out(0, READY)
        elif not self._executing:
            self._executing = True
            self._process(command)
            if self._blocking_until is None:
                self._signal_done(command)

    def _end_stopping(self) -> None:
        if self._stopping is not None:
            self._stopping.finish()
            self._stopping = None

    def _finish_blocking_command(self) -> None:
        if self._blocking_until is not None and self._blocking_until():
            self._blocking_until = None
            self._write_out(0, DONE)

    def _signal_done(self, command: int) -> None:
        if command != STOP_SCRIPT and self.status.program_running:
            self._write_out(0, DONE)

    def _process(self, command: int) -> None:
        if command in MOTION_COMMANDS:
            self.motion_commands += 1
        elif command in STOP_COMMANDS:
            self.stop_commands += 1
        if command not in (SERVOJ, SET_WATCHDOG):
            self._servo_window = None  # after any other motion servoj starts afresh
        handler = self._by_command.get(command)
        if handler is None:
            print(f"ur_controller: rtde_control command {command} not emulated", file=sys.stderr)
            return
        handler()

    def _servo_j(self) -> None:
        # Registers 6/7 (speed, acceleration) are unused by servoj, as on the real controller.
        t, lookahead, gain = self._doubles(8, 3)
        self.servo = {"t": t, "lookahead_time": lookahead, "gain": gain}
        # servoj follows the newest target the client sent, smoothed over lookahead_time as
        # the controller does: the client's 500 Hz and ours alias (a cycle with no new target,
        # then one with two), and followed raw, that stop-and-double-step would jerk the arm.
        if self._servo_window is None or self._servo_window.lookahead_s != lookahead:
            self._servo_window = ServoLookahead(lookahead, self.cycle_s)
        self.plant.command_position(self._servo_window.smoothed(self._doubles(0, 6)))

    def _set_watchdog(self) -> None:
        # rtde_set_watchdog("input_int_register_<int offset>", read_input_float_reg(0), "stop")
        frequency = self.registers.double_in(0, self.offsets.float_offset)
        if not (math.isfinite(frequency) and frequency > 0.0):
            # A URScript runtime error ends the program (the manual gives no valid range; a
            # frequency that is not positive cannot describe a period).
            print(f"ur_controller: rtde_set_watchdog: min_frequency {frequency} is not positive; "
                  "program stopped", file=sys.stderr)
            self.stop()
            return
        self.watchdogs.arm(f"input_int_register_{self.offsets.int_offset}", frequency)

    def _move_j(self) -> None:
        target = self._doubles(0, 6)
        self.plant.command_position(target)
        if self.registers.int_in(1, self.offsets.int_offset) != 1:  # synchronous moveJ
            self._blocking_until = lambda: _arrived(self.plant, target)

    def _doubles(self, first: int, count: int) -> list[float]:
        offset = self.offsets.float_offset
        return [self.registers.double_in(first + i, offset) for i in range(count)]

    def _write_out(self, index: int, value: int) -> None:
        self.registers.set_int_out(index, self.offsets.int_offset, value)


def _arrived(plant: Plant, target: list[float]) -> bool:
    q = plant.state().q
    return max(abs(a - b) for a, b in zip(q, target, strict=True)) < ARRIVED_RAD


class ServoLookahead:
    """servoj's lookahead: the plant follows the mean of the targets of the last
    ``lookahead_time`` (one per cycle, a repeated target included). A missed or doubled
    target moves that mean by one cycle's step divided by the window, not by a whole step;
    the price is a lag of half the lookahead, as on the controller."""

    def __init__(self, lookahead_s: float, cycle_s: float) -> None:
        self.lookahead_s = lookahead_s
        self._size = max(1, round(min(max(lookahead_s, 0.03), 0.2) / cycle_s))
        self._targets: list[list[float]] = []

    def smoothed(self, target: list[float]) -> list[float]:
        if not self._targets:
            self._targets = [target] * self._size
        self._targets = [*self._targets[1:], target]
        return [sum(column) / self._size for column in zip(*self._targets, strict=True)]
