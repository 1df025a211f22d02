"""The controller's own state words (robot mode, safety, program) and its register bank.

These are the controller's side of the numbers: the driver keeps its own table
(``drivers/ur_rtde/tables.py``) so that a mistake in one is not silently mirrored in the other.
Values from the UR RTDE guide and the URScript manual.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

from stubs.ur_controller.ur_types import parse_register


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


class SafetyMode(IntEnum):
    NORMAL = 1
    REDUCED = 2
    PROTECTIVE_STOP = 3
    RECOVERY = 4
    SAFEGUARD_STOP = 5
    SYSTEM_EMERGENCY_STOP = 6
    ROBOT_EMERGENCY_STOP = 7
    VIOLATION = 8
    FAULT = 9


class RuntimeState(IntEnum):
    STOPPING = 0
    STOPPED = 1
    PLAYING = 2
    PAUSING = 3
    PAUSED = 4
    RESUMING = 5


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


class RobotStatusBit(IntEnum):
    POWER_ON = 0
    PROGRAM_RUNNING = 1
    TEACH_BUTTON = 2
    POWER_BUTTON = 3


@dataclass(slots=True)
class ControllerStatus:
    """What the controller reports about itself every cycle.

    It boots as an arm that an operator has already powered on and released (RUNNING, safety
    NORMAL) with no program running: the state in which ur_rtde can upload its script.
    """

    robot_mode: RobotMode = RobotMode.RUNNING
    safety_mode: SafetyMode = SafetyMode.NORMAL
    safety_bits: int = 1 << SafetyBit.NORMAL
    runtime_state: RuntimeState = RuntimeState.STOPPED
    speed_scaling: float = 1.0
    target_speed_fraction: float = 1.0

    @property
    def program_running(self) -> bool:
        return self.runtime_state is RuntimeState.PLAYING

    @property
    def robot_status_bits(self) -> int:
        powered = self.robot_mode in (RobotMode.POWER_ON, RobotMode.IDLE, RobotMode.RUNNING)
        return (powered << RobotStatusBit.POWER_ON) | (
            self.program_running << RobotStatusBit.PROGRAM_RUNNING
        )

    def enter_safety_stop(self, mode: SafetyMode, bits: tuple[SafetyBit, ...]) -> None:
        self.safety_mode = mode
        self.safety_bits = sum(1 << bit for bit in bits)
        self.runtime_state = RuntimeState.STOPPED

    def recover(self) -> None:
        """What the operator's "unlock protective stop" / "power on, brake release" leaves."""
        self.robot_mode = RobotMode.RUNNING
        self.safety_mode = SafetyMode.NORMAL
        self.safety_bits = 1 << SafetyBit.NORMAL
        self.speed_scaling = 1.0


@dataclass(slots=True)
class RegisterBank:
    """General purpose registers, and which RTDE session owns each input (for IN_USE)."""

    values: dict[str, float | int | bool] = field(default_factory=dict)
    owners: dict[str, int] = field(default_factory=dict)

    def read(self, name: str) -> float | int | bool:
        value = self.values.get(name)
        if value is not None:
            return value
        register = parse_register(name)
        if register is None or register.kind == "int":
            return 0
        return 0.0 if register.kind == "double" else False

    def write(self, names: list[str], values: list[object]) -> None:
        for name, value in zip(names, values, strict=True):
            self.values[name] = value  # type: ignore[assignment]

    def taken_by_other(self, name: str, session: int) -> bool:
        owner = self.owners.get(name)
        return owner is not None and owner != session

    def claim(self, names: list[str], session: int) -> None:
        for name in names:
            self.owners[name] = session

    def release(self, session: int) -> None:
        for name in [n for n, owner in self.owners.items() if owner == session]:
            del self.owners[name]

    def int_in(self, index: int, offset: int) -> int:
        return int(self.read(f"input_int_register_{index + offset}"))

    def double_in(self, index: int, offset: int) -> float:
        return float(self.read(f"input_double_register_{index + offset}"))

    def set_int_out(self, index: int, offset: int, value: int) -> None:
        self.values[f"output_int_register_{index + offset}"] = value
