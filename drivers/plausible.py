"""Where the arm is, believed only from a plausible reading: the core's own check, in a driver.

After a stop a driver has no commanded position that says where the arm is: the stop's ramp
(stopJ, a CiA 402 quick stop, a Dynamixel goal set to where the servo is) left it short of or
past the last setpoint, and only a reading says where. Taken as a target, one glitched reading
(an encoder or a frame reporting a joint 0.5 rad off) is a motion the device makes at once. So
a driver judges every joint reading it takes with :func:`assurance.plausibility.judge`, the
check the core makes of every state sample, with the bounds the core derives from the same
limits (its velocity and acceleration limits, the default tolerances, the control period),
and takes a target from a reading only if it is plausible; otherwise from the last plausible
one (:meth:`LastPlausible.believed`).

Until ``configure`` (no limits yet) every reading is believed, as before this check.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from assurance.limits import JointLimits
from assurance.plausibility import Bounds, Track, judge
from drivers.base import ControlConfig


class LastPlausible:
    """The driver's record of its readings, judged as the core judges its samples."""

    def __init__(self) -> None:
        self._bounds: Bounds | None = None
        self._with_velocity = False
        self._track: Track | None = None

    def configure(self, control: ControlConfig) -> None:
        """Judge by ``control``'s limits from now on (the record starts again)."""
        given = len(control.a_max) == control.dof and all(
            np.isfinite(a) and a > 0 for a in control.a_max)
        # Without acceleration limits the reported velocities' path cannot be bounded: the
        # readings are judged by the velocity limits alone (no reported velocity is used).
        acceleration = control.a_max if given else (1.0,) * control.dof
        limits = JointLimits(lower=np.array(control.q_lower, dtype=float),
                             upper=np.array(control.q_upper, dtype=float),
                             velocity=np.array(control.v_max, dtype=float),
                             acceleration=np.array(acceleration, dtype=float))
        self._bounds = Bounds.of(limits, control.period_ns)
        self._with_velocity = given
        self._track = None

    def judge(self, t_ns: int, q: Sequence[float], qd: Sequence[float] = ()) -> bool:
        """Judge one reading of the joints (``qd``: the velocities read with it, if any);
        True if plausible (always, before :meth:`configure`)."""
        if self._bounds is None:
            return True
        velocity = np.array(qd, dtype=float) if (self._with_velocity and len(qd) == len(q)) \
            else None
        verdict = judge(self._track, t_ns, np.array(q, dtype=float), velocity, self._bounds)
        self._track = verdict.track
        return verdict.plausible

    def believed(self, t_ns: int, q: Sequence[float], qd: Sequence[float] = ()
                 ) -> tuple[float, ...] | None:
        """Where the arm is by this reading: ``q`` if it is plausible, else the last plausible
        reading; None when no reading was plausible yet (the caller knows better)."""
        if self.judge(t_ns, q, qd):
            return tuple(float(v) for v in q)
        if self._track is None:
            return None
        return tuple(float(v) for v in self._track.anchor_q)
