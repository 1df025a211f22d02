"""From the core's decision for a tick to the command a driver receives.

The core says who owns the period and where it may go; this module turns that into one joint
command with the right law: the setpoint interpolator for policy actions and holds (so every
stream, every stop and every hand-over stays inside the velocity, acceleration and jerk
limits), the planner's trajectory for classical moves, the impedance law in contact, a plain
stop or a device hold where the core asks for one. Hand-overs restart the interpolator from the
last commanded state, so there is no jump when an owner changes.
"""

from __future__ import annotations

import numpy as np

from assurance.fallback import Command as Cmd
from assurance.fallback import Owner
from drivers.base import Command, CommandKind
from kernel.core.tick import TickCommand
from skills.assembly import AssemblyRunner, Sensed
from skills.contact import ContactOwner, ContactState
from skills.interpolator import SetpointInterpolator
from skills.trajectory import MotionLimits


class MotionController:
    def __init__(
        self, limits: MotionLimits, q0: np.ndarray, runner: AssemblyRunner,
        contact: ContactOwner, period_ns: int, impedance: bool = True,
    ) -> None:
        self.limits = limits
        self.runner, self.contact = runner, contact
        self.period_ns, self.dt_s = period_ns, period_ns * 1e-9
        self.impedance = impedance
        self.interpolator = SetpointInterpolator(limits, np.asarray(q0, float))
        self.commanded = np.asarray(q0, dtype=float).copy()

    def command(self, tick: TickCommand, s: Sensed) -> Command:
        kind, owner = tick.command, tick.owner
        if kind is Cmd.STOP:
            return self._device(CommandKind.STOP, s)
        if kind is Cmd.HOLD and owner is Owner.HUMAN:
            return self._device(CommandKind.HOLD, s)
        if owner is Owner.CONTACT:
            return self._contact(tick, s)
        if owner is Owner.PLANNER and kind in (Cmd.SETPOINT, Cmd.RETREAT):
            return self._planned(s)
        target = tick.target if tick.target is not None else s.q
        return self._interpolated(np.asarray(target)[: self.limits.dof], s)

    def _interpolated(self, target: np.ndarray, s: Sensed) -> Command:
        clipped = np.clip(target, self.limits.lower, self.limits.upper)
        setpoint = self.interpolator.update(clipped, s.t_ns)
        return self._position(setpoint.position)

    def _planned(self, s: Sensed) -> Command:
        sample = self.runner.planner_setpoint(self.dt_s)
        if sample is None:  # the planner owns the tick but has no move: hold still
            return self._interpolated(self.commanded, s)
        self.interpolator.reset(sample.position, sample.velocity)
        return self._position(sample.position)

    def _contact(self, tick: TickCommand, s: Sensed) -> Command:
        if tick.command is Cmd.RETREAT:
            self.contact.begin_retreat(s.q)
        elif self.contact.state is ContactState.IDLE:
            self.contact.hold_at(s.q)
        bounded = tick.target if tick.sent is not None else None
        law = self.contact.step(s.t_ns, self.dt_s, s.force_norm, bounded)
        self.interpolator.reset(law.q)
        self.commanded = law.q.copy()
        kind = CommandKind.IMPEDANCE if self.impedance else CommandKind.POSITION
        return Command(kind=kind, q=tuple(law.q.tolist()), gripper=self.runner.gripper,
                       stiffness=tuple(law.stiffness.tolist()) if self.impedance else (),
                       damping=tuple(law.damping.tolist()) if self.impedance else ())

    def _position(self, q: np.ndarray) -> Command:
        self.commanded = np.asarray(q, dtype=float).copy()
        return Command(kind=CommandKind.POSITION, q=tuple(self.commanded.tolist()),
                       gripper=self.runner.gripper)

    def _device(self, kind: CommandKind, s: Sensed) -> Command:
        """The device's own hold or stop; the interpolator restarts from where the arm is."""
        self.interpolator.reset(s.q)
        self.commanded = np.asarray(s.q, dtype=float).copy()
        return Command(kind=kind, gripper=self.runner.gripper)
