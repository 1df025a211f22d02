"""One controller cycle's worth of output data, and how each RTDE output variable is read from it.

A :class:`Frame` is taken once per cycle under the controller lock; every RTDE session then packs
its own recipe from the same frame, so two clients never see two different robots.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from stubs.plant.base import PlantState
from stubs.ur_controller.io_board import VOLTAGE_INPUTS, IOBoard
from stubs.ur_controller.status import ControllerStatus, RegisterBank, RobotMode
from stubs.ur_controller.ur_types import STRUCT_FORMAT, URType, parse_register

JOINT_RUNNING = 253  # joint_mode of a joint under position control (UR JointMode.RUNNING)
JOINT_POWER_OFF = 239
NOMINAL_VOLTAGE = 48.0
ROOM_TEMPERATURE = 30.0

# UR5e Denavit-Hartenberg parameters (Universal Robots, "DH parameters for calculations of
# kinematics and dynamics"), used to report a plausible TCP pose.
_DH_D = (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996)
_DH_A = (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0)
_DH_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)


@dataclass(frozen=True, slots=True)
class Frame:
    timestamp: float
    plant: PlantState
    status: ControllerStatus
    registers: dict[str, float | int | bool]
    execution_time: float
    digital_output_bits: int = 0
    analog_inputs: tuple[float, float] = (0.0, 0.0)


def take_frame(
    timestamp: float, plant: PlantState, status: ControllerStatus, registers: RegisterBank,
    io: IOBoard, execution_time: float,
) -> Frame:
    """Copy what the cycle produced (call under the controller lock)."""
    snapshot = ControllerStatus(
        status.robot_mode, status.safety_mode, status.safety_bits, status.runtime_state,
        status.speed_scaling, status.target_speed_fraction,
    )
    return Frame(timestamp, plant, snapshot, dict(registers.values), execution_time,
                 io.digital_output_bits, io.analog_inputs(plant))


def tcp_pose(q: tuple[float, ...]) -> tuple[float, ...]:
    """Forward kinematics of a UR5e: (x, y, z, rx, ry, rz) with a rotation vector."""
    transform = np.eye(4)
    for theta, d, a, alpha in zip(q, _DH_D, _DH_A, _DH_ALPHA, strict=True):
        ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
        transform = transform @ np.array(
            [[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
             [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]]
        )
    return (*transform[:3, 3].tolist(), *_rotation_vector(transform[:3, :3]))


def _rotation_vector(rotation: np.ndarray) -> tuple[float, float, float]:
    angle = math.acos(max(-1.0, min(1.0, (np.trace(rotation) - 1.0) / 2.0)))
    if angle < 1e-9:
        return (0.0, 0.0, 0.0)
    if math.pi - angle < 1e-6:  # axis from the symmetric part when sin(angle) vanishes
        axis = np.sqrt(np.maximum((np.diag(rotation) + 1.0) / 2.0, 0.0))
        return tuple((axis * angle).tolist())  # type: ignore[return-value]
    axis = np.array([rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0],
                     rotation[1, 0] - rotation[0, 1]]) / (2.0 * math.sin(angle))
    return tuple((axis * angle).tolist())  # type: ignore[return-value]


Provider = Callable[[Frame], object]


def _joint_modes(frame: Frame) -> tuple[int, ...]:
    running = frame.status.robot_mode is RobotMode.RUNNING
    return ((JOINT_RUNNING if running else JOINT_POWER_OFF),) * 6


PROVIDERS: dict[str, Provider] = {
    "timestamp": lambda f: f.timestamp,
    "target_q": lambda f: f.plant.q,
    "actual_q": lambda f: f.plant.q,
    "target_qd": lambda f: f.plant.qd,
    "actual_qd": lambda f: f.plant.qd,
    "target_current": lambda f: f.plant.effort,
    "actual_current": lambda f: f.plant.effort,
    "target_moment": lambda f: f.plant.effort,
    "actual_current_as_torque": lambda f: f.plant.effort,
    "actual_TCP_pose": lambda f: tcp_pose(f.plant.q),
    "target_TCP_pose": lambda f: tcp_pose(f.plant.q),
    "actual_TCP_force": lambda f: f.plant.wrench,
    "ft_raw_wrench": lambda f: f.plant.wrench,
    "joint_temperatures": lambda f: (ROOM_TEMPERATURE,) * 6,
    "actual_execution_time": lambda f: f.execution_time,
    "robot_mode": lambda f: int(f.status.robot_mode),
    "joint_mode": _joint_modes,
    "safety_mode": lambda f: int(f.status.safety_mode),
    "safety_status": lambda f: int(f.status.safety_mode),
    "speed_scaling": lambda f: f.status.speed_scaling,
    "target_speed_fraction": lambda f: f.status.target_speed_fraction,
    "actual_main_voltage": lambda f: NOMINAL_VOLTAGE,
    "actual_robot_voltage": lambda f: NOMINAL_VOLTAGE,
    "actual_joint_voltage": lambda f: (NOMINAL_VOLTAGE,) * 6,
    "runtime_state": lambda f: int(f.status.runtime_state),
    "robot_status_bits": lambda f: f.status.robot_status_bits,
    "safety_status_bits": lambda f: f.status.safety_bits,
    "tool_temperature": lambda f: ROOM_TEMPERATURE,
    "actual_digital_output_bits": lambda f: f.digital_output_bits,
    "standard_analog_input0": lambda f: f.analog_inputs[0],
    "standard_analog_input1": lambda f: f.analog_inputs[1],
    "analog_io_types": lambda f: VOLTAGE_INPUTS,
}


def provider_for(name: str, kind: URType) -> Provider:
    """How to read ``name`` from a frame: a known quantity, a register, or the type's zero."""
    if name in PROVIDERS:
        return PROVIDERS[name]
    if parse_register(name) is not None:
        zero = _zero(kind)
        return lambda f: f.registers.get(name, zero)
    zero = _zero(kind)
    return lambda f: zero


def _zero(kind: URType) -> object:
    count = STRUCT_FORMAT[kind][1]
    scalar: object = 0.0 if kind in (URType.DOUBLE, URType.VECTOR3D, URType.VECTOR6D) else 0
    if kind is URType.BOOL:
        scalar = False
    return scalar if count == 1 else (scalar,) * count
