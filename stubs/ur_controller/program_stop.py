"""A program stop as the dashboard's ``stop`` runs it: the arm decelerates, then the program ends.

UR's dashboard manual (3.3 and later): ``stop`` "stops running program and returns when stopping
is completed". Meanwhile the controller reports runtime state STOPPING (0), the program is no
longer running (commands are not executed), and the arm decelerates to rest under power; then
STOPPED (1). UR publishes no deceleration for a program stop; the emulator brings every joint to
rest at :data:`DECELERATION_RAD_S2` from the speed it had (measure the real one on the arm).
"""

from __future__ import annotations

import math
import threading

from stubs import robot_model as rm
from stubs.plant.base import Plant

DECELERATION_RAD_S2 = 10.0
"""The emulator's assumption for a program stop (a real arm's depends on speed, payload, pose)."""


class ProgramStop:
    """One stop in progress; :meth:`step` runs once per controller cycle."""

    def __init__(self, plant: Plant, cycle_s: float,
                 deceleration: float = DECELERATION_RAD_S2) -> None:
        self.plant = plant
        self.done = threading.Event()
        """Set once the arm is at rest and the program has ended (the dashboard answers then)."""
        self._step = deceleration * cycle_s
        # A measured speed can exceed, for an instant, what a joint may be commanded (a
        # contact, a servo's overshoot: 3.4 rad/s seen at the elbow when a trial was stopped
        # mid-motion); the ramp starts from at most the joint's limit, as a drive's would,
        # instead of the plant refusing the command and the controller's cycle dying.
        self._velocity = [math.copysign(min(abs(v), limit), v)
                          for v, limit in zip(plant.state().qd, rm.JOINT_VELOCITY_LIMIT,
                                              strict=True)]

    def step(self) -> bool:
        """One cycle of deceleration; True (and the plant holds) once every joint is at rest."""
        self._velocity = [math.copysign(max(0.0, abs(v) - self._step), v)
                          for v in self._velocity]
        if any(self._velocity):
            self.plant.command_velocity(self._velocity)
            return False
        self.finish()
        return True

    def finish(self) -> None:
        """At rest now (or cut short: a safety stop, a new program): hold where the arm is."""
        self.plant.hold()
        self.done.set()
