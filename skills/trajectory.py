"""Joint trajectories on ruckig: setpoint interpolation, braking to a hold, point-to-point moves.

Three uses, one set of limits (:class:`MotionLimits`, per joint velocity, acceleration, jerk and
position):

- :class:`skills.interpolator.SetpointInterpolator` turns a stream of action setpoints (a new
  target every action period, e.g. 20 ms) into one jerk-limited setpoint per control period
  (2 ms), passing through each target at the stream's own velocity.
- :func:`decelerate_to_hold` brings a moving joint vector to rest as fast as the limits allow
  (the queue ran dry, or a hold was ordered).
- :func:`plan_joint_move` is a time-optimal rest-to-rest move on a straight line in joint
  space, for classical transport and retreat.

ruckig 0.19 (community build) ignores ``min/max_position``, so position limits are enforced
here: targets must be inside them, pass-through velocities are zeroed where the joint could not
brake before its limit, and every planned trajectory's position extrema are checked. Invalid
input raises ``ValueError`` with a plain message, never a ruckig error.

Pure: no I/O, threads or clocks; time is an argument (integer nanoseconds).
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass

import numpy as np
from ruckig import (
    ControlInterface,
    InputParameter,
    Result,
    Ruckig,
    RuckigError,
    Synchronization,
    Trajectory,
)

from assurance.limits import JointLimits

NS = 1e-9
OK_RESULTS = (Result.Working, Result.Finished)
_STILL = 1e-9


@dataclass(frozen=True, slots=True, eq=False)
class MotionLimits:
    """Per-joint limits: rad, rad/s, rad/s², rad/s³. Arrays are copied and made read-only."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray

    def __post_init__(self) -> None:
        arrays = {name: np.array(getattr(self, name), dtype=float)
                  for name in ("lower", "upper", "velocity", "acceleration", "jerk")}
        n = arrays["lower"].shape
        if len(n) != 1 or n[0] == 0:
            raise ValueError(f"MotionLimits need 1-D arrays, got lower of shape {n}")
        for name, array in arrays.items():
            if array.shape != n:
                raise ValueError(f"MotionLimits.{name} has shape {array.shape}, expected {n}")
            if np.any(np.isnan(array)):
                raise ValueError(f"MotionLimits.{name} contains NaN")
        for name in ("velocity", "acceleration", "jerk"):
            if not np.all(np.isfinite(arrays[name]) & (arrays[name] > 0)):
                raise ValueError(f"MotionLimits.{name} must be positive and finite")
        if np.any(arrays["lower"] > arrays["upper"]):
            raise ValueError("a lower position limit exceeds its upper limit")
        for name, array in arrays.items():
            array.setflags(write=False)
            object.__setattr__(self, name, array)

    @property
    def dof(self) -> int:
        return int(self.lower.shape[0])

    @classmethod
    def uniform(cls, dof: int, position: float, velocity: float, acceleration: float,
                jerk: float) -> MotionLimits:
        """Symmetric limits, the same for every joint (tests and examples)."""
        full = np.ones(dof)
        return cls(-position * full, position * full, velocity * full, acceleration * full,
                   jerk * full)

    @classmethod
    def from_joint_limits(cls, limits: JointLimits, jerk: float | np.ndarray) -> MotionLimits:
        """The arm dimensions of the projection's limits (the gripper dimension dropped)."""
        mask = limits.arm_mask
        jerk_array = np.broadcast_to(np.asarray(jerk, dtype=float), (limits.dim,))
        return cls(limits.lower[mask], limits.upper[mask], limits.velocity[mask],
                   limits.acceleration[mask], jerk_array[mask])

    def contains(self, q: np.ndarray, tolerance: float = 0.0) -> bool:
        q = np.asarray(q, dtype=float)
        return bool(np.all((q >= self.lower - tolerance) & (q <= self.upper + tolerance)))


@dataclass(frozen=True, slots=True, eq=False)
class JointSample:
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


class JointTrajectory:
    """A planned trajectory: sample it at any time, ask its duration and extent.

    Either a ruckig trajectory over the joints, or (for straight-line moves) a one-dimensional
    ruckig trajectory of a path parameter ``s`` with ``q = origin + s·direction``.
    """

    def __init__(self, trajectory: Trajectory, origin: np.ndarray | None = None,
                 direction: np.ndarray | None = None) -> None:
        self._trajectory = trajectory
        self._origin, self._direction = origin, direction
        extrema = trajectory.position_extrema
        low = np.array([bound.min for bound in extrema])
        high = np.array([bound.max for bound in extrema])
        if direction is not None:
            ends = (origin + low[0] * direction, origin + high[0] * direction)
            low, high = np.minimum(*ends), np.maximum(*ends)
        self.position_min, self.position_max = low, high

    @property
    def duration(self) -> float:
        """Seconds from the start to rest at the end."""
        return float(self._trajectory.duration)

    @property
    def duration_ns(self) -> int:
        return int(np.ceil(self._trajectory.duration / NS))

    def sample(self, t: float) -> JointSample:
        """State ``t`` seconds after the start; before 0 is the start, after the end the end."""
        if not np.isfinite(t):
            raise ValueError(f"cannot sample a trajectory at t={t}")
        position, velocity, acceleration = self._trajectory.at_time(
            min(max(float(t), 0.0), self.duration))
        if self._direction is None:
            return JointSample(np.array(position), np.array(velocity), np.array(acceleration))
        line = self._direction
        return JointSample(self._origin + position[0] * line, velocity[0] * line,
                           acceleration[0] * line)

    def within(self, limits: MotionLimits, tolerance: float = 1e-9) -> bool:
        """True when every joint stays inside its position limits for the whole trajectory."""
        return bool(np.all(self.position_min >= limits.lower - tolerance)
                    and np.all(self.position_max <= limits.upper + tolerance))


def plan_joint_move(q0: np.ndarray, q1: np.ndarray, limits: MotionLimits) -> JointTrajectory:
    """Time-optimal rest-to-rest move from ``q0`` to ``q1`` on a straight joint-space line.

    Planned as one path parameter ``s`` from 0 to 1 whose velocity, acceleration and jerk
    limits are the tightest joint limit divided by that joint's share of the move: every joint
    is then the same fraction of the way at every instant (ruckig's own phase
    synchronisation falls back to time synchronisation when the joints' limits differ).

    Raises:
        ValueError: a vector has the wrong length, is not finite, or lies outside the limits.
    """
    start = checked_position(q0, limits, "move start")
    goal = checked_position(q1, limits, "move goal")
    direction = goal - start
    # Joints moving less than a nanoradian do not constrain the timing: their share of the
    # move would turn into path limits too large for ruckig's arithmetic.
    moving = np.abs(direction) > _STILL
    inp = InputParameter(1)
    inp.current_position = inp.current_velocity = inp.current_acceleration = [0.0]
    inp.target_velocity = inp.target_acceleration = [0.0]
    if moving.any():
        share = np.abs(direction[moving])
        inp.target_position = [1.0]
        inp.max_velocity = [float(np.min(limits.velocity[moving] / share))]
        inp.max_acceleration = [float(np.min(limits.acceleration[moving] / share))]
        inp.max_jerk = [float(np.min(limits.jerk[moving] / share))]
    else:  # already there: a zero-length plan
        inp.target_position = [0.0]
        inp.max_velocity = inp.max_acceleration = inp.max_jerk = [1.0]
    trajectory = Trajectory(1)
    _calculate_into(inp, trajectory, "joint move")
    return JointTrajectory(trajectory, start, direction)


def decelerate_to_hold(
    q: np.ndarray, qd: np.ndarray, limits: MotionLimits, qdd: np.ndarray | None = None
) -> JointTrajectory:
    """Bring every joint to rest as fast as its acceleration and jerk limits allow.

    Each joint brakes independently (its own shortest stop), so the joint-space path may bend;
    the returned trajectory's ``within(limits)`` says whether the stop stays inside the
    position limits (braking is still the best available action when it does not).

    Raises:
        ValueError: a vector has the wrong length or is not finite.
    """
    inp = ruckig_input(limits, checked_vector(q, limits.dof, "hold position"),
                 checked_vector(qd, limits.dof, "hold velocity"),
                 None if qdd is None else checked_vector(qdd, limits.dof, "hold acceleration"))
    inp.control_interface = ControlInterface.Velocity
    inp.target_velocity = np.zeros(limits.dof)
    inp.synchronization = Synchronization.No
    return _calculate(inp, limits.dof, "deceleration to hold")


def checked_vector(values: np.ndarray, dof: int, what: str) -> np.ndarray:
    array = np.array(values, dtype=float)
    if array.shape != (dof,):
        raise ValueError(f"{what} needs {dof} values, got shape {array.shape}")
    if not all(map(math.isfinite, array.tolist())):
        raise ValueError(f"{what} is not finite: {array.tolist()}")
    return array


def checked_position(values: np.ndarray, limits: MotionLimits, what: str) -> np.ndarray:
    array = np.array(values, dtype=float)
    if array.shape != (limits.dof,):
        raise ValueError(f"{what} needs {limits.dof} values, got shape {array.shape}")
    # Python comparisons on a few floats: numpy's .all() alone costs microseconds here.
    values, lower, upper = array.tolist(), limits.lower.tolist(), limits.upper.tolist()
    if not (all(map(operator.le, lower, values)) and all(map(operator.le, values, upper))):
        j = next(i for i, (lo, v, hi) in enumerate(zip(lower, values, upper, strict=True))
                 if not lo <= v <= hi)  # NaN lands here too
        raise ValueError(f"{what}[{j}] = {values[j]:.6g} is not inside [{lower[j]:.6g}, "
                         f"{upper[j]:.6g}]")
    return array


def ruckig_input(limits: MotionLimits, q: np.ndarray, qd: np.ndarray | None = None,
           qdd: np.ndarray | None = None) -> InputParameter:
    zeros = np.zeros(limits.dof)
    inp = InputParameter(limits.dof)
    inp.current_position = q
    inp.current_velocity = zeros if qd is None else qd
    inp.current_acceleration = zeros if qdd is None else qdd
    inp.target_velocity = zeros
    inp.target_acceleration = zeros
    inp.max_velocity = limits.velocity
    inp.max_acceleration = limits.acceleration
    inp.max_jerk = limits.jerk
    return inp


def _calculate(inp: InputParameter, dof: int, what: str) -> JointTrajectory:
    trajectory = Trajectory(dof)
    _calculate_into(inp, trajectory, what)
    return JointTrajectory(trajectory)


def _calculate_into(inp: InputParameter, trajectory: Trajectory, what: str) -> None:
    try:
        result = Ruckig(trajectory.degrees_of_freedom).calculate(inp, trajectory)
    except RuckigError as error:
        raise ValueError(f"{what} rejected: {ruckig_message(error)}") from None
    if result not in OK_RESULTS:
        raise ValueError(f"{what} could not be planned ({result})")


def ruckig_message(error: RuckigError) -> str:
    return str(error).replace("[ruckig]", "").strip()
