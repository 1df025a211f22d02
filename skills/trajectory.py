"""Joint trajectories on ruckig: setpoint interpolation, braking to a hold, point-to-point moves.

Three uses, one set of limits (:class:`MotionLimits`, per joint velocity, acceleration, jerk and
position):

- :class:`SetpointInterpolator` turns a stream of action setpoints (a new target every action
  period, e.g. 20 ms) into one jerk-limited setpoint per control period (2 ms). Each new target
  is planned to be reached one stream interval after it arrives, at the stream's own velocity,
  so a steadily moving stream is followed smoothly instead of stop-and-go.
- :func:`decelerate_to_hold` brings a moving joint vector to rest as fast as the limits allow
  (the queue ran dry, or a hold was ordered).
- :func:`plan_joint_move` is a rest-to-rest move on a straight line in joint space, for
  classical transport and retreat.

ruckig 0.19 (community build) ignores ``min/max_position``, so position limits are enforced
here: targets must be inside them, pass-through velocities are zeroed where the joint could not
brake before its limit, and every planned trajectory's position extrema are checked. Invalid
input raises ``ValueError`` with a plain message, never a ruckig error.

Pure: no I/O, threads or clocks; time is an argument (integer nanoseconds).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ruckig import (
    ControlInterface,
    InputParameter,
    OutputParameter,
    Result,
    Ruckig,
    RuckigError,
    Synchronization,
    Trajectory,
)

from assurance.limits import JointLimits

_NS = 1e-9
_OK_RESULTS = (Result.Working, Result.Finished)


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

    @property
    def lower_list(self) -> list[float]:
        return self.lower.tolist()

    @property
    def upper_list(self) -> list[float]:
        return self.upper.tolist()

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
    """A planned ruckig trajectory: sample it at any time, ask its duration and extent."""

    def __init__(self, trajectory: Trajectory) -> None:
        self._trajectory = trajectory
        extrema = trajectory.position_extrema
        self.position_min = np.array([bound.min for bound in extrema])
        self.position_max = np.array([bound.max for bound in extrema])

    @property
    def duration(self) -> float:
        """Seconds from the start to rest at the end."""
        return float(self._trajectory.duration)

    @property
    def duration_ns(self) -> int:
        return int(np.ceil(self._trajectory.duration / _NS))

    def sample(self, t: float) -> JointSample:
        """State ``t`` seconds after the start; before 0 is the start, after the end the end."""
        if not np.isfinite(t):
            raise ValueError(f"cannot sample a trajectory at t={t}")
        position, velocity, acceleration = self._trajectory.at_time(
            min(max(float(t), 0.0), self.duration))
        return JointSample(np.array(position), np.array(velocity), np.array(acceleration))

    def within(self, limits: MotionLimits, tolerance: float = 1e-9) -> bool:
        """True when every joint stays inside its position limits for the whole trajectory."""
        return _extrema_within(self._trajectory, limits, tolerance)


def plan_joint_move(q0: np.ndarray, q1: np.ndarray, limits: MotionLimits) -> JointTrajectory:
    """Time-optimal rest-to-rest move from ``q0`` to ``q1`` on a straight joint-space line.

    Raises:
        ValueError: a vector has the wrong length, is not finite, or lies outside the limits.
    """
    start = _checked_position(q0, limits, "move start")
    goal = _checked_position(q1, limits, "move goal")
    inp = _input(limits, start)
    inp.target_position = goal
    inp.synchronization = Synchronization.Phase
    trajectory = _calculate(inp, limits.dof, "joint move")
    if not trajectory.within(limits):
        raise ValueError("planned joint move leaves the position limits")
    return trajectory


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
    inp = _input(limits, _checked_vector(q, limits.dof, "hold position"),
                 _checked_vector(qd, limits.dof, "hold velocity"),
                 None if qdd is None else _checked_vector(qdd, limits.dof, "hold acceleration"))
    inp.control_interface = ControlInterface.Velocity
    inp.target_velocity = np.zeros(limits.dof)
    inp.synchronization = Synchronization.No
    return _calculate(inp, limits.dof, "deceleration to hold")


@dataclass(frozen=True, slots=True)
class InterpolatorConfig:
    control_period_ns: int = 2_000_000
    max_stream_interval_ns: int = 100_000_000
    """Targets further apart than this are treated as a fresh start (no stream velocity)."""
    velocity_feedforward: bool = True
    """Pass through each target at the stream's velocity instead of stopping at it."""

    def __post_init__(self) -> None:
        if self.control_period_ns <= 0 or self.max_stream_interval_ns <= 0:
            raise ValueError("control_period_ns and max_stream_interval_ns must be positive")


@dataclass(frozen=True, slots=True, eq=False)
class Setpoint:
    t_ns: int
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


class SetpointInterpolator:
    """Follow a stream of joint targets with one limited setpoint per control period.

    Call :meth:`update` once per control tick with the current action target (the same target
    again until the next action arrives). A target that differs from the previous one is a new
    stream sample: it is planned to be reached one stream interval later (the time since the
    previous sample) at the stream's velocity. When the stream stops (no new target for longer
    than its interval) the pass-through velocity is dropped and the setpoints settle at the last
    target. Each call advances exactly one control period.
    """

    def __init__(self, limits: MotionLimits, q0: np.ndarray,
                 config: InterpolatorConfig | None = None) -> None:
        self.limits = limits
        self.config = config or InterpolatorConfig()
        self._otg = Ruckig(limits.dof, self.config.control_period_ns * _NS)
        self._half_inverse_acceleration = 0.5 / limits.acceleration
        self._acceleration_over_jerk = limits.acceleration / limits.jerk
        self._out = OutputParameter(limits.dof)
        self.reset(q0)

    def reset(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """Restart from a measured state (at rest unless ``qd`` is given); forget the stream."""
        position = _checked_position(q, self.limits, "interpolator start")
        velocity = None if qd is None else _checked_vector(qd, self.limits.dof, "start velocity")
        self._inp = _input(self.limits, position, velocity)
        self._inp.target_position = position
        self._target = position
        self._target_t_ns: int | None = None
        self._stream_interval_ns: int | None = None
        self._last_t_ns: int | None = None
        zeros = np.zeros(self.limits.dof)
        self._setpoint = Setpoint(0, position, zeros if velocity is None else velocity, zeros)
        self._otg.reset()

    @property
    def setpoint(self) -> Setpoint:
        """The last setpoint returned (the start state before the first update)."""
        return self._setpoint

    def update(self, target: np.ndarray, now_ns: int) -> Setpoint:
        """The setpoint for ``now_ns + control_period_ns``, following ``target``.

        Raises:
            ValueError: ``target`` is malformed or outside the position limits, or ``now_ns``
                went backwards.
        """
        goal = _checked_position(target, self.limits, "interpolator target")
        if self._last_t_ns is not None and now_ns < self._last_t_ns:
            raise ValueError(f"time went backwards: {now_ns} < {self._last_t_ns}")
        self._last_t_ns = now_ns
        if goal.tobytes() != self._target.tobytes():  # exact change, cheaper than array_equal
            self._new_stream_sample(goal, now_ns)
        elif self._stream_is_stale(now_ns):
            self._end_stream()
        self._advance()
        return self._setpoint

    def _new_stream_sample(self, goal: np.ndarray, now_ns: int) -> None:
        interval = None if self._target_t_ns is None else now_ns - self._target_t_ns
        if interval is not None and not 0 < interval <= self.config.max_stream_interval_ns:
            interval = None
        velocity = np.zeros(self.limits.dof)
        if interval is not None and self.config.velocity_feedforward:
            velocity = self._brakeable((goal - self._target) / (interval * _NS), goal)
        self._target, self._target_t_ns, self._stream_interval_ns = goal, now_ns, interval
        self._inp.target_position = goal
        self._inp.target_velocity = velocity
        self._inp.minimum_duration = None if interval is None else interval * _NS

    def _stream_is_stale(self, now_ns: int) -> bool:
        if self._stream_interval_ns is None:
            return False
        return now_ns - self._target_t_ns > self._stream_interval_ns + self.config.control_period_ns

    def _end_stream(self) -> None:
        self._stream_interval_ns = None
        self._inp.target_velocity = np.zeros(self.limits.dof)
        self._inp.minimum_duration = None

    def _brakeable(self, velocity: np.ndarray, at: np.ndarray) -> np.ndarray:
        """Stream velocity, clipped to the limit and zeroed where it could not stop in time."""
        lim = self.limits
        velocity = velocity.clip(-lim.velocity, lim.velocity)
        speed = np.abs(velocity)
        room = np.where(velocity > 0, lim.upper - at, at - lim.lower)
        # Stopping distance from `speed` at zero acceleration, jerk-limited (an upper bound):
        # v²/2a while braking at the limit, plus v·a/j for the jerk ramps.
        stop = speed * (speed * self._half_inverse_acceleration + self._acceleration_over_jerk)
        velocity[stop > room] = 0.0
        return velocity

    def _advance(self) -> None:
        result = self._step()
        if self._out.new_calculation and not self._planned_within_limits():
            # The pass-through velocity would carry a joint past a limit: settle instead.
            self._end_stream()
            result = self._step()
        if result not in _OK_RESULTS:
            raise ValueError(f"interpolator could not plan from the current state ({result})")
        out = self._out
        self._setpoint = Setpoint(
            self._last_t_ns + self.config.control_period_ns, np.array(out.new_position),
            np.array(out.new_velocity), np.array(out.new_acceleration))
        out.pass_to_input(self._inp)

    def _step(self) -> Result:
        try:
            return self._otg.update(self._inp, self._out)
        except RuckigError as error:
            raise ValueError(f"interpolator input rejected: {_ruckig_message(error)}") from None

    def _planned_within_limits(self) -> bool:
        return _extrema_within(self._out.trajectory, self.limits, 1e-9)


def _extrema_within(trajectory: Trajectory, limits: MotionLimits, tolerance: float) -> bool:
    # A plain loop: six scalar comparisons cost less than two numpy reductions here.
    return all(
        lower - tolerance <= bound.min and bound.max <= upper + tolerance
        for bound, lower, upper in zip(trajectory.position_extrema, limits.lower_list,
                                       limits.upper_list, strict=True)
    )


def _checked_vector(values: np.ndarray, dof: int, what: str) -> np.ndarray:
    array = np.array(values, dtype=float)
    if array.shape != (dof,):
        raise ValueError(f"{what} needs {dof} values, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{what} is not finite: {array.tolist()}")
    return array


def _checked_position(values: np.ndarray, limits: MotionLimits, what: str) -> np.ndarray:
    array = np.array(values, dtype=float)
    if array.shape != (limits.dof,):
        raise ValueError(f"{what} needs {limits.dof} values, got shape {array.shape}")
    inside = (array >= limits.lower) & (array <= limits.upper)  # False for NaN as well
    if not inside.all():
        j = int(np.flatnonzero(~inside)[0])
        raise ValueError(f"{what}[{j}] = {array[j]:.6g} is not inside "
                         f"[{limits.lower[j]:.6g}, {limits.upper[j]:.6g}]")
    return array


def _input(limits: MotionLimits, q: np.ndarray, qd: np.ndarray | None = None,
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
    try:
        result = Ruckig(dof).calculate(inp, trajectory)
    except RuckigError as error:
        raise ValueError(f"{what} rejected: {_ruckig_message(error)}") from None
    if result not in _OK_RESULTS:
        raise ValueError(f"{what} could not be planned ({result})")
    return JointTrajectory(trajectory)


def _ruckig_message(error: RuckigError) -> str:
    return str(error).replace("[ruckig]", "").strip()
