"""Joint trajectories on ruckig: setpoint interpolation, braking to a hold, point-to-point moves.

Three uses, one set of limits (:class:`MotionLimits`, per joint velocity, acceleration, jerk and
position):

- :class:`SetpointInterpolator` turns a stream of action setpoints (a new target every action
  period, e.g. 20 ms) into one jerk-limited setpoint per control period (2 ms). Each joint
  passes through each new target at the stream's own velocity, so a steadily moving stream is
  followed smoothly instead of stop-and-go.
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
    OutputParameter,
    Profile,
    Result,
    Ruckig,
    RuckigError,
    Synchronization,
    Trajectory,
)

from assurance.limits import JointLimits

_NS = 1e-9
_OK_RESULTS = (Result.Working, Result.Finished)
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
        return int(np.ceil(self._trajectory.duration / _NS))

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
    start = _checked_position(q0, limits, "move start")
    goal = _checked_position(q1, limits, "move goal")
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
    stream sample; each joint heads for it on its own time-optimal profile and passes through
    it at the stream's velocity (estimated from the last two samples), then keeps that velocity
    until the next sample. When the stream stops (no new sample for longer than its interval),
    each joint that has reached the last target drops the pass-through velocity and settles
    back on it, overshooting by at most its braking distance from the stream's velocity. Each
    call advances exactly one control period.

    The pass-through velocity is withheld (zero) for a joint when it would carry the joint
    past a position limit, or when the joint could only reach it by first moving away from
    the target (a "run-up"); both are checked on every plan.
    """

    def __init__(self, limits: MotionLimits, q0: np.ndarray,
                 config: InterpolatorConfig | None = None) -> None:
        self.limits = limits
        self.config = config or InterpolatorConfig()
        self._otg = Ruckig(limits.dof, self.config.control_period_ns * _NS)
        self._out = OutputParameter(limits.dof)
        self._half_inverse_acceleration = 0.5 / limits.acceleration
        self._acceleration_over_jerk = limits.acceleration / limits.jerk
        self.reset(q0)

    def reset(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """Restart from a measured state (at rest unless ``qd`` is given); forget the stream."""
        position = _checked_position(q, self.limits, "interpolator start")
        velocity = None if qd is None else _checked_vector(qd, self.limits.dof, "start velocity")
        self._inp = _input(self.limits, position, velocity)
        self._inp.target_position = position
        # Each joint on its own time-optimal profile: synchronising joints that must arrive
        # with different non-zero velocities lands ruckig in "blocked" duration intervals,
        # where the common duration it finds makes joints reverse on the way.
        self._inp.synchronization = Synchronization.No
        self._target = position
        self._target_velocity = np.zeros(self.limits.dof)
        self._target_t_ns: int | None = None
        self._stream_interval_ns: int | None = None
        self._last_t_ns: int | None = None
        self._arrived = np.full(self.limits.dof, qd is None)
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
            self._settle(self._arrived)
        self._advance()
        return self._setpoint

    def _new_stream_sample(self, goal: np.ndarray, now_ns: int) -> None:
        interval = None if self._target_t_ns is None else now_ns - self._target_t_ns
        if interval is not None and not 0 < interval <= self.config.max_stream_interval_ns:
            interval = None
        velocity = np.zeros(self.limits.dof)
        if interval is not None and self.config.velocity_feedforward:
            velocity = (goal - self._target) / (interval * _NS)
            velocity = self._reachable(self._brakeable(velocity, goal), goal)
        self._target, self._target_t_ns, self._stream_interval_ns = goal, now_ns, interval
        self._inp.target_position = goal
        self._set_target_velocity(velocity)

    def _stream_is_stale(self, now_ns: int) -> bool:
        if self._stream_interval_ns is None:
            return False
        return now_ns - self._target_t_ns > self._stream_interval_ns + self.config.control_period_ns

    def _settle(self, joints: np.ndarray) -> None:
        """Drop the pass-through velocity of ``joints`` (a boolean mask)."""
        if joints.any() and np.any(self._target_velocity[joints] != 0.0):
            velocity = self._target_velocity.copy()
            velocity[joints] = 0.0
            self._set_target_velocity(velocity)
        if np.all(self._target_velocity == 0.0):
            self._stream_interval_ns = None

    def _set_target_velocity(self, velocity: np.ndarray) -> None:
        self._target_velocity = velocity
        self._inp.target_velocity = velocity

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

    def _reachable(self, velocity: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Cap each pass-through speed at what the joint can reach on its way to ``goal``.

        Speeding up from ``v0`` to ``v1`` at acceleration ``a`` and jerk ``j`` takes at most
        ``(v0 + v1)/2 · ((v1 - v0)/a + a/j)`` of distance, so distance ``d`` allows at least
        ``v1² + k·v1 = v0² − k·v0 + 2·a·d`` with ``k = a²/j``. Keeping the current speed is
        always allowed (the bound is loose for small speed-ups). The estimate ignores the
        current acceleration; :meth:`_runs_up` catches what it lets through.
        """
        lim = self.limits
        distance = goal - self._setpoint.position
        direction = np.sign(distance)
        v0 = np.maximum(self._setpoint.velocity * direction, 0.0)
        k = lim.acceleration * self._acceleration_over_jerk
        rhs = np.maximum(v0 * v0 - k * v0 + 2 * lim.acceleration * np.abs(distance), 0.0)
        speed_up = 0.9 * (np.sqrt(k * k + 4 * rhs) - k) / 2  # 0.9: the ramp is idealised
        reachable = np.maximum(speed_up, v0)
        same_way = velocity * direction > 0
        return np.where(same_way, direction * np.minimum(np.abs(velocity), reachable), 0.0)

    def _advance(self) -> None:
        result = self._step()
        if self._out.new_calculation:
            rejected = self._rejected_pass_through()
            if rejected.any():
                self._settle(rejected)
                result = self._step()
        if result not in _OK_RESULTS:
            raise ValueError(f"interpolator could not plan from the current state ({result})")
        out = self._out
        self._arrived = np.array(out.trajectory.independent_min_durations) <= out.time + 1e-12
        self._setpoint = Setpoint(
            self._last_t_ns + self.config.control_period_ns, np.array(out.new_position),
            np.array(out.new_velocity), np.array(out.new_acceleration))
        out.pass_to_input(self._inp)

    def _step(self) -> Result:
        try:
            return self._otg.update(self._inp, self._out)
        except RuckigError as error:
            raise ValueError(f"interpolator input rejected: {_ruckig_message(error)}") from None

    def _rejected_pass_through(self) -> np.ndarray:
        """Joints whose new plan, with a pass-through velocity, leaves the limits or runs up."""
        trajectory = self._out.trajectory
        lower, upper = self.limits.lower.tolist(), self.limits.upper.tolist()
        rejected = np.zeros(self.limits.dof, dtype=bool)
        for joint, velocity in enumerate(self._target_velocity.tolist()):
            if velocity == 0.0:
                continue
            bound = trajectory.position_extrema[joint]
            outside = bound.min < lower[joint] - 1e-9 or bound.max > upper[joint] + 1e-9
            profile = trajectory.profiles[0][joint]
            rejected[joint] = outside or _runs_up(profile, 1.0 if velocity > 0 else -1.0)
        return rejected


def _runs_up(profile: Profile, direction: float) -> bool:
    """True when the profile's velocity points against ``direction`` at any instant.

    Velocity is piecewise quadratic: check every phase boundary and every phase's vertex.
    """
    velocities, accelerations, jerks = profile.v, profile.a, profile.j  # each read copies
    # v and a hold one more entry than t and j (the end state): zip stops at the phases.
    for duration, v, a, j in zip(profile.t, velocities, accelerations, jerks, strict=False):
        if v * direction < -1e-12:
            return True
        if duration > 0.0 and j != 0.0 and 0.0 < -a / j < duration:
            vertex = v - a * a / (2 * j)
            if vertex * direction < -1e-12:
                return True
    return velocities[-1] * direction < -1e-12


def _checked_vector(values: np.ndarray, dof: int, what: str) -> np.ndarray:
    array = np.array(values, dtype=float)
    if array.shape != (dof,):
        raise ValueError(f"{what} needs {dof} values, got shape {array.shape}")
    if not all(map(math.isfinite, array.tolist())):
        raise ValueError(f"{what} is not finite: {array.tolist()}")
    return array


def _checked_position(values: np.ndarray, limits: MotionLimits, what: str) -> np.ndarray:
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
    _calculate_into(inp, trajectory, what)
    return JointTrajectory(trajectory)


def _calculate_into(inp: InputParameter, trajectory: Trajectory, what: str) -> None:
    try:
        result = Ruckig(trajectory.degrees_of_freedom).calculate(inp, trajectory)
    except RuckigError as error:
        raise ValueError(f"{what} rejected: {_ruckig_message(error)}") from None
    if result not in _OK_RESULTS:
        raise ValueError(f"{what} could not be planned ({result})")


def _ruckig_message(error: RuckigError) -> str:
    return str(error).replace("[ruckig]", "").strip()
