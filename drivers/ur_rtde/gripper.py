"""A two-finger gripper on a UR tool digital output, its position fed back on an analog input.

The common UR cell wiring for a simple electric or pneumatic gripper: it closes while a tool
digital output is high and opens while it is low, and reports its opening as a 0-10 V (or
4-20 mA) signal. ur_rtde 1.6.5 cannot read the tool analog inputs (see ``tables``), so the
signal comes in on a standard analog input of the control box.

The gripper is binary: a commanded opening below half the maximum closes it, any other
opening (half or more) opens it. The reported opening is the measured signal scaled linearly
from ``gripper_feedback_closed`` (0 m) to ``gripper_feedback_open`` (the maximum opening).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from drivers.ur_rtde import tables

if TYPE_CHECKING:
    from drivers.ur_rtde.settings import URSettings


@dataclass(frozen=True, slots=True)
class GripperWiring:
    output: int
    """Tool digital output index (0 or 1); high = closed."""
    feedback: str
    """RTDE output name of the analog input carrying the position signal."""
    signal_closed: float
    signal_open: float
    max_opening_m: float

    @classmethod
    def from_settings(cls, settings: URSettings) -> GripperWiring | None:
        """The wiring the settings describe, or None when the arm has no gripper."""
        if settings.gripper_output is None:
            return None
        return cls(settings.gripper_output, settings.gripper_feedback,
                   settings.gripper_feedback_closed, settings.gripper_feedback_open,
                   settings.gripper_max_opening_m)

    @property
    def getter(self) -> str:
        """The ur_rtde receive method that reads the feedback input."""
        return tables.GRIPPER_FEEDBACK_INPUTS[self.feedback]

    def output_high(self, digital_output_bits: int) -> bool:
        """This gripper's tool output in ``actual_digital_output_bits`` (tool outputs: bit 16+)."""
        return bool(digital_output_bits >> (tables.TOOL_OUTPUT_SHIFT + self.output) & 1)

    def closes(self, opening_m: float) -> bool:
        """Whether a commanded opening means "closed" (output high) for this binary gripper."""
        return opening_m < self.max_opening_m / 2

    def opening_m(self, signal: float) -> float:
        """The measured opening; clamped, since sensor noise may read past either end."""
        fraction = (signal - self.signal_closed) / (self.signal_open - self.signal_closed)
        return min(max(fraction, 0.0), 1.0) * self.max_opening_m
