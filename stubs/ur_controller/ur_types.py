"""The RTDE variable table of a UR e-Series controller: name → wire type, and since which version.

Source: Universal Robots, "Real-Time Data Exchange (RTDE) Guide" (field names and types), which
is what the real controller answers to a setup request. ur_rtde unpacks data packages with its
own type table and ignores the types string we send back, so every variable must be packed with
exactly the type listed here: a VECTOR6INT32 packed as doubles would desynchronise the client.
A name that is not in the table (or is newer than the emulated version) answers ``NOT_FOUND``.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from enum import StrEnum


class URType(StrEnum):
    BOOL = "BOOL"
    UINT8 = "UINT8"
    UINT32 = "UINT32"
    UINT64 = "UINT64"
    INT32 = "INT32"
    DOUBLE = "DOUBLE"
    VECTOR3D = "VECTOR3D"
    VECTOR6D = "VECTOR6D"
    VECTOR6INT32 = "VECTOR6INT32"
    VECTOR6UINT32 = "VECTOR6UINT32"


NOT_FOUND = "NOT_FOUND"
IN_USE = "IN_USE"

# struct format (big-endian on the wire) and element count of each type
STRUCT_FORMAT: dict[URType, tuple[str, int]] = {
    URType.BOOL: ("?", 1),
    URType.UINT8: ("B", 1),
    URType.UINT32: ("I", 1),
    URType.UINT64: ("Q", 1),
    URType.INT32: ("i", 1),
    URType.DOUBLE: ("d", 1),
    URType.VECTOR3D: ("3d", 3),
    URType.VECTOR6D: ("6d", 6),
    URType.VECTOR6INT32: ("6i", 6),
    URType.VECTOR6UINT32: ("6I", 6),
}

Version = tuple[int, int, int]

_ALWAYS: Version = (0, 0, 0)
_D, _V6, _V3 = URType.DOUBLE, URType.VECTOR6D, URType.VECTOR3D

# name: (type, first e-Series version that has it)
OUTPUTS: dict[str, tuple[URType, Version]] = {
    "timestamp": (_D, _ALWAYS),
    "target_q": (_V6, _ALWAYS),
    "target_qd": (_V6, _ALWAYS),
    "target_qdd": (_V6, _ALWAYS),
    "target_current": (_V6, _ALWAYS),
    "target_moment": (_V6, _ALWAYS),
    "actual_q": (_V6, _ALWAYS),
    "actual_qd": (_V6, _ALWAYS),
    "actual_current": (_V6, _ALWAYS),
    "actual_current_window": (_V6, (5, 23, 0)),
    "joint_control_output": (_V6, _ALWAYS),
    "actual_TCP_pose": (_V6, _ALWAYS),
    "actual_TCP_speed": (_V6, _ALWAYS),
    "actual_TCP_force": (_V6, _ALWAYS),
    "target_TCP_pose": (_V6, _ALWAYS),
    "target_TCP_speed": (_V6, _ALWAYS),
    "actual_digital_input_bits": (URType.UINT64, _ALWAYS),
    "joint_temperatures": (_V6, _ALWAYS),
    "actual_execution_time": (_D, _ALWAYS),
    "robot_mode": (URType.INT32, _ALWAYS),
    "joint_mode": (URType.VECTOR6INT32, _ALWAYS),
    "safety_mode": (URType.INT32, _ALWAYS),
    "safety_status": (URType.INT32, (5, 5, 0)),
    "actual_tool_accelerometer": (_V3, _ALWAYS),
    "speed_scaling": (_D, _ALWAYS),
    "target_speed_fraction": (_D, _ALWAYS),
    "actual_momentum": (_D, _ALWAYS),
    "actual_main_voltage": (_D, _ALWAYS),
    "actual_robot_voltage": (_D, _ALWAYS),
    "actual_robot_current": (_D, _ALWAYS),
    "actual_joint_voltage": (_V6, _ALWAYS),
    "actual_digital_output_bits": (URType.UINT64, _ALWAYS),
    "runtime_state": (URType.UINT32, _ALWAYS),
    "elbow_position": (_V3, (5, 0, 0)),
    "elbow_velocity": (_V3, (5, 0, 0)),
    "robot_status_bits": (URType.UINT32, _ALWAYS),
    "safety_status_bits": (URType.UINT32, _ALWAYS),
    "analog_io_types": (URType.UINT32, _ALWAYS),
    "standard_analog_input0": (_D, _ALWAYS),
    "standard_analog_input1": (_D, _ALWAYS),
    "standard_analog_output0": (_D, _ALWAYS),
    "standard_analog_output1": (_D, _ALWAYS),
    "io_current": (_D, _ALWAYS),
    "euromap67_input_bits": (URType.UINT32, _ALWAYS),
    "euromap67_output_bits": (URType.UINT32, _ALWAYS),
    "euromap67_24V_voltage": (_D, _ALWAYS),
    "euromap67_24V_current": (_D, _ALWAYS),
    "tool_mode": (URType.UINT32, _ALWAYS),
    "tool_analog_input_types": (URType.UINT32, _ALWAYS),
    "tool_analog_input0": (_D, _ALWAYS),
    "tool_analog_input1": (_D, _ALWAYS),
    "tool_output_voltage": (URType.INT32, _ALWAYS),
    "tool_output_current": (_D, _ALWAYS),
    "tool_temperature": (_D, _ALWAYS),
    "tcp_force_scalar": (_D, _ALWAYS),
    "output_bit_registers0_to_31": (URType.UINT32, _ALWAYS),
    "output_bit_registers32_to_63": (URType.UINT32, _ALWAYS),
    "input_bit_registers0_to_31": (URType.UINT32, _ALWAYS),
    "input_bit_registers32_to_63": (URType.UINT32, _ALWAYS),
    "tool_output_mode": (URType.UINT8, (5, 2, 0)),
    "tool_digital_output0_mode": (URType.UINT8, (5, 2, 0)),
    "tool_digital_output1_mode": (URType.UINT8, (5, 2, 0)),
    "payload": (_D, (5, 5, 1)),
    "payload_cog": (_V3, (5, 5, 1)),
    "payload_inertia": (_V6, (5, 11, 0)),
    "script_control_line": (URType.UINT32, (5, 6, 0)),
    "ft_raw_wrench": (_V6, (5, 9, 0)),
    "joint_position_deviation_ratio": (_V6, (5, 15, 0)),
    "collision_detection_ratio": (_D, (5, 15, 0)),
    "actual_current_as_torque": (_V6, (5, 23, 0)),
}

INPUTS: dict[str, tuple[URType, Version]] = {
    "speed_slider_mask": (URType.UINT32, _ALWAYS),
    "speed_slider_fraction": (_D, _ALWAYS),
    "standard_digital_output_mask": (URType.UINT8, _ALWAYS),
    "standard_digital_output": (URType.UINT8, _ALWAYS),
    "configurable_digital_output_mask": (URType.UINT8, _ALWAYS),
    "configurable_digital_output": (URType.UINT8, _ALWAYS),
    "tool_digital_output_mask": (URType.UINT8, _ALWAYS),
    "tool_digital_output": (URType.UINT8, _ALWAYS),
    "standard_analog_output_mask": (URType.UINT8, _ALWAYS),
    "standard_analog_output_type": (URType.UINT8, _ALWAYS),
    "standard_analog_output_0": (_D, _ALWAYS),
    "standard_analog_output_1": (_D, _ALWAYS),
    "input_bit_registers0_to_31": (URType.UINT32, _ALWAYS),
    "input_bit_registers32_to_63": (URType.UINT32, _ALWAYS),
    "external_force_torque": (_V6, (5, 0, 0)),
}

# General purpose registers: 0-23 are the "lower range", 24-47 the "upper range" (5.3+);
# bit registers 64-127 are addressed one by one.
_REGISTER = re.compile(r"^(input|output)_(int|double|bit)_register_(\d+)$")
_REGISTER_TYPES = {"int": URType.INT32, "double": URType.DOUBLE, "bit": URType.BOOL}


@dataclass(frozen=True, slots=True)
class Register:
    direction: str
    """"input" (written by RTDE clients) or "output" (written by the URScript program)."""
    kind: str
    """"int", "double" or "bit"."""
    index: int


def parse_register(name: str) -> Register | None:
    match = _REGISTER.match(name)
    if match is None:
        return None
    direction, kind, index = match.group(1), match.group(2), int(match.group(3))
    valid = 64 <= index <= 127 if kind == "bit" else 0 <= index <= 47
    return Register(direction, kind, index) if valid else None


def _register_type(name: str, version: Version) -> URType | None:
    register = parse_register(name)
    if register is None:
        return None
    if register.kind != "bit" and register.index >= 24 and version < (5, 3, 0):
        return None
    return _REGISTER_TYPES[register.kind]


def output_type(name: str, version: Version) -> URType | None:
    """The type of an output variable (inputs can be read back as outputs), or None."""
    register_type = _register_type(name, version)
    if register_type is not None:
        return register_type
    entry = OUTPUTS.get(name) or INPUTS.get(name)
    if entry is None or version < entry[1]:
        return None
    return entry[0]


def input_type(name: str, version: Version) -> URType | None:
    """The type of a variable an RTDE client may write, or None."""
    register = parse_register(name)
    if register is not None:
        return _register_type(name, version) if register.direction == "input" else None
    entry = INPUTS.get(name)
    if entry is None or version < entry[1]:
        return None
    return entry[0]


def recipe_struct(types: list[URType]) -> struct.Struct:
    """One precompiled big-endian struct for a whole recipe (all its fields in order)."""
    return struct.Struct(">" + "".join(STRUCT_FORMAT[t][0] for t in types))


def flatten(types: list[URType], values: list[object]) -> list[object]:
    """Vector values spread into their elements, in the order ``recipe_struct`` expects."""
    flat: list[object] = []
    for kind, value in zip(types, values, strict=True):
        if STRUCT_FORMAT[kind][1] == 1:
            flat.append(value)
        else:
            flat.extend(value)  # type: ignore[arg-type]
    return flat


def unflatten(types: list[URType], flat: tuple[object, ...]) -> list[object]:
    """The inverse of :func:`flatten`, for decoding client data packages."""
    values: list[object] = []
    position = 0
    for kind in types:
        count = STRUCT_FORMAT[kind][1]
        chunk = flat[position : position + count]
        values.append(chunk[0] if count == 1 else tuple(chunk))
        position += count
    return values
