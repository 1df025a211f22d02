"""The gripper drive's link to the plant: its CSP target is the commanded opening, its actual
position is the plant's measured opening (``PlantState.gripper``, metres).

The joint drives share the plant's ``command_position``; the gripper has an input of its own,
``command_gripper``. While the gripper drive does not follow a target (not yet enabled,
disabled, quick stop, FAULT) the plant's gripper command is left as it was: an electric gripper's
self-locking gear keeps the fingers, and the grip on a held part, where they were, where a joint
drive's brake would hold its measured position.
"""

from __future__ import annotations

from stubs.cia402_drive.drive import EmulatedDrive
from stubs.plant.base import Plant, PlantState
from stubs.robot_model import GRIPPER_MAX_OPENING


class GripperLink:
    def __init__(self, drive: EmulatedDrive, max_opening_m: float = GRIPPER_MAX_OPENING) -> None:
        self.drive = drive
        self.max_opening_m = max_opening_m
        """The fingers' mechanical stops: a target beyond them only presses against them."""
        self._last: tuple[int, float] | None = None
        self._velocity = 0.0

    def command(self, plant: Plant, opening_now: float) -> None:
        """At SYNC, before the plant steps: pass an enabled CSP drive's target on."""
        if self.drive.follows_target:
            target = self.drive.joint_target(opening_now)
            plant.command_gripper(min(max(target, 0.0), self.max_opening_m))

    def measure(self, state: PlantState) -> None:
        """After the plant stepped: the opening becomes the drive's actual position."""
        self.drive.update_actual(state.gripper, self._rate(state), 0.0)

    def _rate(self, state: PlantState) -> float:
        """Opening speed by finite difference (the plant reports no finger velocity); kept as
        it was when the plant did not step since the last SYNC."""
        if self._last is not None and state.t_ns > self._last[0]:
            self._velocity = (state.gripper - self._last[1]) / ((state.t_ns - self._last[0]) * 1e-9)
        self._last = (state.t_ns, state.gripper)
        return self._velocity
