"""The emulated UR controller: one control cycle at 500 Hz over a plant, three servers, faults.

Each cycle checks the RTDE watchdogs the script armed (a silent client stops the program, see
:mod:`stubs.ur_controller.watchdog`), runs the uploaded control script once (its ``sync()``),
lets the gripper follow its tool output (:mod:`~stubs.ur_controller.io_board`), takes one
:class:`Frame`, and sends every started RTDE session its data package. The plant steps inside
that cycle, as the arm follows a real controller's servo loop: a free-running stepper thread
beside it aliased against the client's 500 Hz stream (two setpoints in one physics step, none in
the next), and the plant's velocity feed-forward turned that into jerks of tens of newtons at
the wrist.
Lock order: controller lock, then the plant lock.
"""

from __future__ import annotations

import contextlib
import socket
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import msgspec

from stubs.fault_control import Handler
from stubs.plant.base import Plant
from stubs.reading_glitch import ReadingGlitch
from stubs.ur_controller.dashboard import serve_dashboard, serve_script_port
from stubs.ur_controller.frame import Frame, take_frame
from stubs.ur_controller.io_board import GripperWiring, IOBoard
from stubs.ur_controller.listener import Listener
from stubs.ur_controller.rtde_server import RTDESession, ServerContext
from stubs.ur_controller.script import ControlScript
from stubs.ur_controller.status import (
    ControllerStatus,
    RegisterBank,
    RobotMode,
    SafetyBit,
    SafetyMode,
)
from stubs.ur_controller.watchdog import InputWatchdog, RTDEWatchdogs

RTDE_PORT, DASHBOARD_PORT, SCRIPT_PORT = 30004, 29999, 30003
CB3_MAJOR = 3
STOP_ANSWER_TIMEOUT_S = 10.0


@dataclass(frozen=True, slots=True)
class ControllerConfig:
    host: str
    version: tuple[int, int, int, int] = (5, 11, 1, 108318)
    gripper: GripperWiring = field(default_factory=GripperWiring)
    """Where the cell's gripper is wired (tool output, feedback input)."""

    @property
    def cycle_hz(self) -> float:
        """e-Series controllers run (and publish RTDE) at 500 Hz, CB3 at 125 Hz."""
        return 125.0 if self.version[0] <= CB3_MAJOR else 500.0


class URController:
    def __init__(self, config: ControllerConfig, plant: Plant) -> None:
        self.config = config
        self.plant = plant
        self.status = ControllerStatus()
        self.registers = RegisterBank()
        self.io = IOBoard(config.gripper)
        self.lock = threading.Lock()
        self.plant_lock = threading.Lock()
        """Held for every plant access (the cycle, the world port of the cell's evaluator)."""
        self._steps_per_cycle = max(1, round(1e9 / config.cycle_hz / plant.timestep_ns))
        self.watchdogs = RTDEWatchdogs(1.0 / config.cycle_hz)
        self.script = ControlScript(self.status, self.registers, plant,
                                    1.0 / config.cycle_hz, self.watchdogs)
        self.stalled = False
        self.glitch = ReadingGlitch()
        """An injected reading glitch: the frames report it, the arm does not move by it."""
        self.dashboard_stops = 0
        """Program stops the dashboard's ``stop`` started (tests ask over the control port)."""
        self._sessions: set[RTDESession] = set()
        self._sessions_lock = threading.Lock()
        self._context = ServerContext(config.version, config.cycle_hz, self.registers, self.lock,
                                      self.io, self.watchdogs)
        self._stop = threading.Event()
        self._boot = time.monotonic()
        self._cycle_thread = threading.Thread(target=self._run, name="cycle", daemon=True)
        host = config.host
        self.rtde = Listener(host, RTDE_PORT, self._serve_rtde, "rtde")
        self.dashboard = Listener(host, DASHBOARD_PORT, lambda s: serve_dashboard(s, self),
                                  "dashboard")
        self.script_port = Listener(host, SCRIPT_PORT, lambda s: serve_script_port(s, self),
                                    "script")

    # -- life ---------------------------------------------------------------------------------

    def start(self) -> URController:
        """Bind every port first (fails loudly if one is taken), then start the cycle."""
        for listener in (self.rtde, self.dashboard, self.script_port):
            listener.start()
        self._cycle_thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        for listener in (self.rtde, self.dashboard, self.script_port):
            listener.stop()
        self._drop_sessions()
        if self._cycle_thread.is_alive():
            self._cycle_thread.join(timeout=1.0)

    # -- what the dashboard and the script port ask for ------------------------------------------

    def software_version(self) -> str:
        return ".".join(str(part) for part in self.config.version)

    def load_program(self, name: str, text: str) -> None:
        with self._locked():
            if name == "rtde_control" and self._motion_allowed():
                self.script.load(text)
            else:
                # Programs we do not interpret (or any program during a safety stop) end at once.
                print(f"ur_controller: program {name!r} not started", file=sys.stderr)
                self.script.stop()

    def stop_program(self) -> bool:
        """The dashboard's ``stop``: answers once the arm has decelerated and the program has
        ended (as the manual says from 3.3 on); stopping a stopped program succeeds too
        (ur_rtde relies on it)."""
        with self._locked():
            stopping = self.script.stop_decelerating()
            if stopping is not None:
                self.dashboard_stops += 1
        return stopping is None or stopping.done.wait(STOP_ANSWER_TIMEOUT_S)

    def unlock_protective_stop(self) -> bool:
        with self._locked():
            if self.status.safety_mode is not SafetyMode.PROTECTIVE_STOP:
                return False
            self.status.recover()
        return True

    # -- faults (the fault-control port calls these) ----------------------------------------

    def fault_handlers(self) -> dict[str, Handler]:
        return {
            "protective_stop": lambda _: self._safety_stop(
                SafetyMode.PROTECTIVE_STOP, (SafetyBit.PROTECTIVE_STOP,)),
            "estop": lambda _: self._emergency_stop(),
            "data_stall": lambda _: self._stall(),
            "reading_glitch": self.glitch.start,
            "disconnect": lambda _: self._disconnect(),
            "speed_scaling": lambda request: self._set_speed_scaling(float(request["value"])),
            "clear": lambda _: self._clear(),
            "io_state": lambda _: self._io_state(),
            "status": lambda _: self._status(),
            "lose_io_write": lambda request: self._lose_io_writes(int(request.get("count", 1))),
            "motion": lambda _: self._motion(),
        }

    def _motion(self) -> dict[str, int]:
        """Not a fault: how many motion and stop commands the control script executed."""
        with self.lock:
            return {"motion_commands": self.script.motion_commands,
                    "stop_commands": self.script.stop_commands}

    def _lose_io_writes(self, count: int) -> None:
        with self._locked():
            self.io.lose_writes = count

    def _io_state(self) -> dict[str, object]:
        """Not a fault: what the outputs and the gripper really are (tests, no RTDE needed)."""
        with self._locked():
            return {"digital_output_bits": self.io.digital_output_bits,
                    "gripper_m": self.plant.state().gripper,
                    "output_packages": dict(self.io.packages)}

    def _status(self) -> dict[str, object]:
        """Not a fault: the status words and the armed RTDE watchdogs (tests, no RTDE needed)."""
        with self.lock:
            status = self.status
            return {"robot_mode": int(status.robot_mode), "safety_bits": status.safety_bits,
                    "runtime_state": int(status.runtime_state),
                    "robot_status_bits": status.robot_status_bits,
                    "watchdogs": self.watchdogs.snapshot(),
                    "dashboard_stops": self.dashboard_stops}

    def _safety_stop(self, mode: SafetyMode, bits: tuple[SafetyBit, ...]) -> None:
        # As on the real controller: the program leaves PLAYING, so ur_rtde's commands fail.
        with self._locked():
            self.status.enter_safety_stop(mode, bits)
            self.script.stop()

    def _emergency_stop(self) -> None:
        self._safety_stop(SafetyMode.ROBOT_EMERGENCY_STOP,
                          (SafetyBit.ROBOT_EMERGENCY_STOP, SafetyBit.EMERGENCY_STOP))
        with self.lock:
            self.status.robot_mode = RobotMode.POWER_OFF  # an e-stop cuts arm power

    def _stall(self) -> None:
        # A hung RTDE server: open sessions get no data, new ones are refused. Refused, not
        # accepted: ur_rtde's control interface reconnects on its own after its 2.5 s read
        # deadline, and a reconnect that succeeds starts a second receive thread on the same
        # object (the crash in the shared notes). This emulates the stall a client survives.
        self.rtde.refuse()
        self.stalled = True

    def _disconnect(self) -> None:
        # Refuse first: ur_rtde's receive thread reconnects within milliseconds of the EOF.
        self.rtde.refuse()
        self._drop_sessions()

    def _set_speed_scaling(self, value: float) -> None:
        if not 0.0 <= value <= 1.0:
            raise ValueError(f"speed scaling {value} is outside [0, 1]")
        with self.lock:
            self.status.speed_scaling = value

    def _clear(self) -> None:
        with self._locked():
            self.status.recover()
            self.io.lose_writes = 0
        self.stalled = False
        self.glitch.clear()
        self.rtde.resume()

    # -- the control cycle ----------------------------------------------------------------------

    def _run(self) -> None:
        period = 1.0 / self.config.cycle_hz
        deadline, cycle = time.monotonic(), 0
        while not self._stop.is_set():
            deadline += period
            delay = deadline - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                deadline = time.monotonic()  # fell behind: skip, never burst
            frame = self._cycle()
            if not self.stalled:
                self._publish(frame, cycle)
            cycle += 1

    def _cycle(self) -> Frame:
        started = time.perf_counter()
        with self._locked():
            expired = self.watchdogs.expired()
            if expired is not None:
                self._watchdog_stop(expired)
            self.script.step()
            self.io.drive_gripper(self.plant)
            self.plant.step(self._steps_per_cycle)
            state = self.plant.state()
            state = msgspec.structs.replace(state, q=self.glitch.apply(state.q))
            return take_frame(time.monotonic() - self._boot, state, self.status,
                              self.registers, self.io, time.perf_counter() - started)

    def _watchdog_stop(self, watchdog: InputWatchdog) -> None:
        """rtde_set_watchdog's "stop": the program stops as if stopped from the dashboard."""
        silent_ms = watchdog.silent_cycles * self.watchdogs.cycle_s * 1e3
        print(f"ur_controller: no update of {watchdog.variable} for {silent_ms:.0f} ms (watchdog "
              f"at {watchdog.min_frequency_hz:g} Hz): program stopped", file=sys.stderr)
        self.watchdogs.fired += 1
        self.script.stop()

    def _publish(self, frame: Frame, cycle: int) -> None:
        with self._sessions_lock:
            sessions = [s for s in self._sessions if s.started]
        for session in sessions:
            try:
                session.send_data(frame, cycle)
            except OSError:
                session.close()

    def _serve_rtde(self, sock: socket.socket) -> None:
        session = RTDESession(sock, self._context, self._forget)
        with self._sessions_lock:
            self._sessions.add(session)
        session.serve()

    def _forget(self, session: RTDESession) -> None:
        with self._sessions_lock:
            self._sessions.discard(session)

    def _drop_sessions(self) -> None:
        with self._sessions_lock:
            sessions = list(self._sessions)
        for session in sessions:
            session.close()

    def _motion_allowed(self) -> bool:
        return (self.status.safety_mode is SafetyMode.NORMAL
                and self.status.robot_mode is RobotMode.RUNNING)

    @contextlib.contextmanager
    def _locked(self) -> Iterator[None]:
        with self.lock, self.plant_lock:
            yield
