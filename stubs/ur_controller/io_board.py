"""The controller's digital outputs and analog inputs, and the gripper wired to them.

RTDE clients switch outputs with input recipes of mask/value pairs (ur_rtde's RTDEIOInterface
sends ``tool_digital_output_mask`` + ``tool_digital_output``, and likewise for the standard and
configurable outputs): each data package sets the bits in its mask and leaves the others.
``actual_digital_output_bits`` reports them back: bits 0-7 standard, 8-15 configurable, 16-17
tool, as in the RTDE guide.

The emulated cell has the wiring of a common UR gripper cell, always fitted (a real controller
always has its tool IO): a two-finger gripper closes while tool digital output 0 is high and
opens while it is low, and reports its opening on standard analog input 0 as 0-10 V for
0-0.085 m (the input is in voltage mode in ``analog_io_types``).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass

from stubs import robot_model as rm
from stubs.plant.base import Plant, PlantState

CONFIGURABLE_SHIFT, TOOL_SHIFT = 8, 16
OUTPUT_BITS = {"standard_digital_output": 0xFF, "configurable_digital_output": 0xFF,
               "tool_digital_output": 0b11}
VOLTAGE_INPUTS = 0b0011
"""analog_io_types: bits 0-1 are the standard analog inputs, 1 = voltage (V), 0 = current."""


@dataclass(frozen=True, slots=True)
class GripperWiring:
    tool_output: int = 0
    feedback_input: int = 0
    max_opening_m: float = rm.GRIPPER_MAX_OPENING
    full_scale_v: float = 10.0

    def volts(self, opening_m: float) -> float:
        """The position signal; a real sensor saturates at the ends of its range."""
        fraction = min(max(opening_m / self.max_opening_m, 0.0), 1.0)
        return fraction * self.full_scale_v


class IOBoard:
    """Output bits as the clients set them; the gripper follows its tool output."""

    def __init__(self, wiring: GripperWiring | None = None) -> None:
        self.wiring = wiring or GripperWiring()
        self.outputs = dict.fromkeys(OUTPUT_BITS, 0)
        self.packages: Counter[str] = Counter()
        """How many client packages set each kind of output (tests check writes are rare)."""
        self.lose_writes = 0
        """Output packages still to be lost (the ``lose_io_write`` fault: what ur_rtde's IO
        interface does to its first write after the controller dropped its session)."""
        # Boots with every output low and leaves the gripper as the plant has it.
        self._gripper_closed = False

    def apply(self, names: list[str], values: list[object]) -> None:
        """One client data package: the masked output bits it carries (other fields are
        registers, which the register bank keeps)."""
        package = dict(zip(names, values, strict=True))
        if self.lose_writes and any(name in package for name in OUTPUT_BITS):
            self.lose_writes -= 1
            return
        for name, width in OUTPUT_BITS.items():
            if name in package:
                self.packages[name] += 1
                self.outputs[name] = _masked(self.outputs[name], package, name, width)

    @property
    def digital_output_bits(self) -> int:
        return (self.outputs["standard_digital_output"]
                | self.outputs["configurable_digital_output"] << CONFIGURABLE_SHIFT
                | self.outputs["tool_digital_output"] << TOOL_SHIFT)

    def drive_gripper(self, plant: Plant) -> None:
        """Once per cycle (plant lock held). Only an edge of the output moves the gripper:
        between cycles the world port may reset the plant, and with it the gripper."""
        closed = bool(self.outputs["tool_digital_output"] >> self.wiring.tool_output & 1)
        if closed != self._gripper_closed:
            self._gripper_closed = closed
            plant.command_gripper(0.0 if closed else self.wiring.max_opening_m)

    def analog_inputs(self, state: PlantState) -> tuple[float, float]:
        """standard_analog_input0 and 1, in volts; the one not wired to the gripper reads 0."""
        signal = self.wiring.volts(state.gripper)
        return (signal, 0.0) if self.wiring.feedback_input == 0 else (0.0, signal)


def _masked(current: int, package: Mapping[str, object], name: str, width: int) -> int:
    mask = int(package.get(f"{name}_mask", 0)) & width  # type: ignore[call-overload]
    value = int(package[name]) & width  # type: ignore[call-overload]
    return (current & ~mask) | (value & mask)
