"""Couples the servos' control tables to the plant: goals drive joints, present values come back.

Servo ``ids[j]`` turns plant joint ``j``; its shaft angle is the joint angle, centre tick 2048 at
0 rad. A servo with torque off is limp on real hardware; the plant has no "limp", so the joint
holds where it is (the kinematic plant has no gravity to make the difference visible).

An optional gripper servo (:class:`GripperLink`) drives the plant's gripper instead of a joint:
its goal, while torque is on, is the commanded opening, and its present position reports the
plant's measured opening, both linear between the closed tick (0 m) and the open tick.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from stubs.dynamixel_bus.control_table import Addr, ServoTable
from stubs.plant.realtime import RealtimeStepper
from stubs.reading_glitch import ReadingGlitch
from stubs.robot_model import GRIPPER_MAX_OPENING

TICKS_PER_RAD = 4096 / (2.0 * math.pi)
CENTRE_TICK = 2048
RAD_S_PER_VELOCITY_UNIT = 0.229 * 2.0 * math.pi / 60.0
"""Present Velocity counts 0.229 rev/min."""
AMPS_PER_CURRENT_UNIT = 0.00269
"""Present Current counts 2.69 mA on the XM430."""
TORQUE_PER_AMP = 1.78
"""XM430-W350 at 12 V: 4.1 N·m stall torque at 2.3 A."""
MOVING_THRESHOLD_RAD_S = 0.02
GRIPPER_OPEN_TICKS = 2048
GRIPPER_CLOSED_TICKS = 3072
"""Default gripper end ticks: open at the centre tick, closed a quarter turn further."""


def rad_to_ticks(q: float) -> int:
    return round(q * TICKS_PER_RAD) + CENTRE_TICK


def ticks_to_rad(ticks: int) -> float:
    return (ticks - CENTRE_TICK) / TICKS_PER_RAD


@dataclass(frozen=True, slots=True)
class GripperLink:
    """The gripper servo: which id, and where its ends are in ticks."""

    servo_id: int
    open_ticks: int = GRIPPER_OPEN_TICKS
    closed_ticks: int = GRIPPER_CLOSED_TICKS

    def __post_init__(self) -> None:
        if self.open_ticks == self.closed_ticks:
            raise ValueError(f"gripper open and closed ticks are both {self.open_ticks}")

    def opening(self, ticks: int) -> float:
        """The opening a goal asks for, within the gripper's travel (its end stops)."""
        fraction = (ticks - self.closed_ticks) / (self.open_ticks - self.closed_ticks)
        return min(max(fraction, 0.0), 1.0) * GRIPPER_MAX_OPENING

    def ticks(self, opening: float) -> int:
        fraction = opening / GRIPPER_MAX_OPENING
        return round(self.closed_ticks + fraction * (self.open_ticks - self.closed_ticks))


class PlantLink:
    def __init__(self, stepper: RealtimeStepper, ids: Sequence[int],
                 gripper: GripperLink | None = None) -> None:
        if stepper.plant.dof != len(ids):
            raise ValueError(f"{len(ids)} servo ids for a plant with {stepper.plant.dof} joints")
        self.stepper = stepper
        self.ids = tuple(ids)
        self.gripper = gripper
        self.glitch = ReadingGlitch()
        """An injected reading glitch: what a read reports, never what the servo holds to."""

    def refresh(self, servos: Mapping[int, ServoTable], reported: bool = True) -> None:
        """Copy the plant's measured state into every servo's present-value registers;
        ``reported``: for a read the host asked for (an injected reading glitch shows), not
        for the servos' own use of where they are (a stop, a power-on)."""
        with self.stepper.lock:
            state = self.stepper.plant.state()
        q = self.glitch.apply(state.q) if reported else state.q
        for joint, servo_id in enumerate(self.ids):
            servo = servos[servo_id]
            qd = state.qd[joint] if state.qd else 0.0
            effort = state.effort[joint] if state.effort else 0.0
            servo.set(Addr.PRESENT_POSITION, 4, rad_to_ticks(q[joint]))
            servo.set(Addr.PRESENT_VELOCITY, 4, round(qd / RAD_S_PER_VELOCITY_UNIT))
            servo.set(Addr.PRESENT_CURRENT, 2, _current_units(effort))
            servo.set(Addr.MOVING, 1, int(abs(qd) > MOVING_THRESHOLD_RAD_S))
        if self.gripper is not None:
            # Position only: the plant reports no finger speed or force to fill the others.
            ticks = self.gripper.ticks(state.gripper)
            servos[self.gripper.servo_id].set(Addr.PRESENT_POSITION, 4, ticks)

    def apply(self, servos: Mapping[int, ServoTable]) -> None:
        """Command the plant: torque-on joints go to their goal, torque-off joints stay put."""
        with self.stepper.lock:
            q_now = self.stepper.plant.state().q
            target = [
                ticks_to_rad(servos[servo_id].get(Addr.GOAL_POSITION, 4, signed=True))
                if servos[servo_id].torque_enabled else q_now[joint]
                for joint, servo_id in enumerate(self.ids)
            ]
            try:
                self.stepper.plant.command_position(target)
            except ValueError as error:
                # The plant's joint limits are narrower than a servo's turn: a real joint would
                # hit its end stop, so the joints stay where they are.
                print(f"dynamixel_bus: plant refused goals {target}: {error}", file=sys.stderr)
                self.stepper.plant.hold()
            self._apply_gripper(servos)

    def halt(self, servos: Mapping[int, ServoTable]) -> None:
        """Servos stopped by their Bus Watchdog: with every joint stopped the plant holds where
        it is (dropping the velocity it estimated from the goal stream); otherwise the stopped
        ones go to their goal, which is where they stopped."""
        if not all(servos[servo_id].watchdog_error for servo_id in self.ids):
            self.apply(servos)
            return
        with self.stepper.lock:
            self.stepper.plant.hold()
            self._apply_gripper(servos)

    def _apply_gripper(self, servos: Mapping[int, ServoTable]) -> None:
        """A torque-on gripper goes to its goal; repeating the same opening costs the plant
        nothing, so every write may resend it. Torque off: the fingers stay where they are."""
        if self.gripper is None:
            return
        servo = servos[self.gripper.servo_id]
        if servo.torque_enabled:
            goal = servo.get(Addr.GOAL_POSITION, 4, signed=True)
            self.stepper.plant.command_gripper(self.gripper.opening(goal))


def _current_units(effort_nm: float) -> int:
    units = round(effort_nm / TORQUE_PER_AMP / AMPS_PER_CURRENT_UNIT)
    return max(-32768, min(32767, units))
