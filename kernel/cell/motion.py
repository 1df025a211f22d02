"""From the core's decision for a tick to the command a driver receives.

The core says who owns the period and where it may go; this module turns that into one joint
command with the right law: the setpoint interpolator for policy actions and holds (so every
stream, every stop and every hand-over stays inside the velocity, acceleration and jerk
limits), the planner's trajectory for classical moves, the impedance law in contact, a plain
stop or a device hold where the core asks for one.

Hand-overs never jump: the interpolator restarts from the last commanded state (clipped into
the limits, so a measured overshoot cannot stop a stop), and a planner move that another owner
interrupted is re-planned from rest where the arm was left, after the interpolator has brought
the arm to rest, instead of resuming mid-profile at the speed it had when it was paused.
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
from skills.planner import PlanningError
from skills.trajectory import MotionLimits

RESUME_AT_REST_RAD_S = 1e-3
RESUME_AT_REST_RAD_S2 = 1e-2
RESUME_SETTLED_RAD = 1e-6
"""When the interpolator counts as settled, so a paused planner move may be re-planned from
rest: this close to its latched target, this slow, this little acceleration."""


class MotionController:
    def __init__(
        self, limits: MotionLimits, q0: np.ndarray, runner: AssemblyRunner,
        contact: ContactOwner, period_ns: int, impedance: bool = True,
    ) -> None:
        self.limits = limits
        self.runner, self.contact = runner, contact
        self.period_ns, self.dt_s = period_ns, period_ns * 1e-9
        self.impedance = impedance
        start = np.clip(np.asarray(q0, dtype=float)[: limits.dof], limits.lower, limits.upper)
        self.interpolator = SetpointInterpolator(limits, start)
        self.commanded = self.interpolator.setpoint.position.copy()
        self._planner_had_tick = False
        self._pending_resume = False
        self._resume_target = self.commanded

    def restart_from(self, q: np.ndarray) -> None:
        """Start over from a measured position at rest (after bring-up, at the device's pose)."""
        self._restart(q)
        self._planner_had_tick = self._pending_resume = False

    def command(self, tick: TickCommand, s: Sensed) -> Command:
        kind, owner = tick.command, tick.owner
        planner_tick = owner is Owner.PLANNER and kind in (Cmd.SETPOINT, Cmd.RETREAT)
        resuming = planner_tick and not self._planner_had_tick
        self._planner_had_tick = planner_tick
        if kind is Cmd.STOP:
            return self._device(CommandKind.STOP, s)
        if kind is Cmd.HOLD and owner is Owner.HUMAN:
            return self._device(CommandKind.HOLD, s)
        if owner is Owner.CONTACT:
            return self._contact(tick, s)
        if planner_tick:
            return self._planned(s, resuming)
        target = tick.target if tick.target is not None else s.q
        return self._interpolated(np.asarray(target)[: self.limits.dof], s)

    def _interpolated(self, target: np.ndarray, s: Sensed) -> Command:
        clipped = np.clip(target, self.limits.lower, self.limits.upper)
        setpoint = self.interpolator.update(clipped, s.t_ns)
        return self._position(setpoint.position)

    def _planned(self, s: Sensed, resuming: bool) -> Command:
        if resuming:
            self._resume_target = self.interpolator.setpoint.position.copy()
        if resuming or self._pending_resume:
            self._pending_resume = not self._resume_planner_move()
            if self._pending_resume:  # still moving: settle where the last owner left the arm
                return self._interpolated(self._resume_target, s)
        sample = self.runner.planner_setpoint(self.dt_s)
        if sample is None:  # the planner owns the tick but has no move: hold still
            return self._interpolated(self.commanded, s)
        self.interpolator.reset(sample.position, sample.velocity, sample.acceleration)
        return self._position(sample.position)

    def _resume_planner_move(self) -> bool:
        """Re-plan the planner's move from the interpolator's state; False: not settled yet.

        Settled means arrived at the latched target with velocity *and* acceleration about
        zero: a velocity crossing zero on an overshoot still carries full acceleration, and a
        rest-to-rest plan from there would be a jerk step.
        """
        setpoint = self.interpolator.setpoint
        settled = (
            float(np.abs(setpoint.position - self._resume_target).max()) <= RESUME_SETTLED_RAD
            and float(np.abs(setpoint.velocity).max()) <= RESUME_AT_REST_RAD_S
            and float(np.abs(setpoint.acceleration).max()) <= RESUME_AT_REST_RAD_S2)
        if not settled:
            return False
        try:
            self.runner.resume_move_from(setpoint.position)
        except (PlanningError, ValueError):
            return False  # no rest-to-rest move from here: keep holding, try again next tick
        return True

    def _contact(self, tick: TickCommand, s: Sensed) -> Command:
        if tick.command is Cmd.RETREAT:
            self.contact.begin_retreat(s.q)
        elif self.contact.state is ContactState.IDLE:
            self.contact.hold_at(s.q)
        bounded = tick.target if tick.sent is not None else None
        law = self.contact.step(s.t_ns, self.dt_s, s.force_norm, bounded)
        self._restart(law.q)
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
        command = Command(kind=kind, gripper=self.runner.gripper)
        self._restart(s.q)
        return command

    def _restart(self, q: np.ndarray) -> None:
        self.interpolator.reset(self._inside(q))
        self.commanded = self.interpolator.setpoint.position.copy()

    def _inside(self, q: np.ndarray) -> np.ndarray:
        """A measured position may sit a hair past a limit (tracking overshoot, a human push)
        or, from a faulty device, not be a number: restart inside the limits, keeping the last
        commanded value for any joint that is not finite."""
        position = np.asarray(q, dtype=float)[: self.limits.dof].copy()
        invalid = ~np.isfinite(position)
        position[invalid] = self.commanded[invalid]
        return np.clip(position, self.limits.lower, self.limits.upper)
