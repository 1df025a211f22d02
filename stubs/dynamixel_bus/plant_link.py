"""Couples the servos' control tables to the plant: goals drive joints, present values come back.

Servo ``ids[j]`` turns plant joint ``j``; its shaft angle is the joint angle, centre tick 2048 at
0 rad. A servo with torque off is limp on real hardware; the plant has no "limp", so the joint
holds where it is (the kinematic plant has no gravity to make the difference visible).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping, Sequence

from stubs.dynamixel_bus.control_table import Addr, ServoTable
from stubs.plant.realtime import RealtimeStepper

TICKS_PER_RAD = 4096 / (2.0 * math.pi)
CENTRE_TICK = 2048
RAD_S_PER_VELOCITY_UNIT = 0.229 * 2.0 * math.pi / 60.0
"""Present Velocity counts 0.229 rev/min."""
AMPS_PER_CURRENT_UNIT = 0.00269
"""Present Current counts 2.69 mA on the XM430."""
TORQUE_PER_AMP = 1.78
"""XM430-W350 at 12 V: 4.1 N·m stall torque at 2.3 A."""
MOVING_THRESHOLD_RAD_S = 0.02


def rad_to_ticks(q: float) -> int:
    return round(q * TICKS_PER_RAD) + CENTRE_TICK


def ticks_to_rad(ticks: int) -> float:
    return (ticks - CENTRE_TICK) / TICKS_PER_RAD


class PlantLink:
    def __init__(self, stepper: RealtimeStepper, ids: Sequence[int]) -> None:
        if stepper.plant.dof != len(ids):
            raise ValueError(f"{len(ids)} servo ids for a plant with {stepper.plant.dof} joints")
        self.stepper = stepper
        self.ids = tuple(ids)

    def refresh(self, servos: Mapping[int, ServoTable]) -> None:
        """Copy the plant's measured state into every servo's present-value registers."""
        with self.stepper.lock:
            state = self.stepper.plant.state()
        for joint, servo_id in enumerate(self.ids):
            servo = servos[servo_id]
            qd = state.qd[joint] if state.qd else 0.0
            effort = state.effort[joint] if state.effort else 0.0
            servo.set(Addr.PRESENT_POSITION, 4, rad_to_ticks(state.q[joint]))
            servo.set(Addr.PRESENT_VELOCITY, 4, round(qd / RAD_S_PER_VELOCITY_UNIT))
            servo.set(Addr.PRESENT_CURRENT, 2, _current_units(effort))
            servo.set(Addr.MOVING, 1, int(abs(qd) > MOVING_THRESHOLD_RAD_S))

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


def _current_units(effort_nm: float) -> int:
    units = round(effort_nm / TORQUE_PER_AMP / AMPS_PER_CURRENT_UNIT)
    return max(-32768, min(32767, units))
