"""The setpoint interpolator: a stream of action targets in, one jerk-limited setpoint per
control period out (ruckig), inside the position, velocity, acceleration and jerk limits.

Each joint passes through each new target at the stream's own velocity, so a steadily moving
stream is followed smoothly instead of stop-and-go; hand-overs restart it from a given state.
Pure: no I/O, threads or clocks; time is an argument (integer nanoseconds).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ruckig import (
    OutputParameter,
    Profile,
    Result,
    Ruckig,
    RuckigError,
    Synchronization,
)

from skills.trajectory import (
    NS,
    OK_RESULTS,
    MotionLimits,
    checked_position,
    checked_vector,
    ruckig_input,
    ruckig_message,
)


@dataclass(frozen=True, slots=True)
class InterpolatorConfig:
    control_period_ns: int
    """The control period each call advances: no default, since a wrong one scales every
    motion by the ratio of the periods (an 8 ms loop on a 2 ms default moved at a quarter of
    the asked speed)."""
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
                 config: InterpolatorConfig) -> None:
        self.limits = limits
        self.config = config
        self._otg = Ruckig(limits.dof, self.config.control_period_ns * NS)
        self._out = OutputParameter(limits.dof)
        self._half_inverse_acceleration = 0.5 / limits.acceleration
        self._acceleration_over_jerk = limits.acceleration / limits.jerk
        self.reset(q0)

    def reset(self, q: np.ndarray, qd: np.ndarray | None = None,
              qdd: np.ndarray | None = None) -> None:
        """Restart from a state (at rest unless ``qd``/``qdd`` are given); forget the stream.

        A start acceleration beyond the limits is clipped to them: the state comes from another
        owner's profile, planned with its own limits.
        """
        position = checked_position(q, self.limits, "interpolator start")
        velocity = None if qd is None else checked_vector(qd, self.limits.dof, "start velocity")
        acceleration = None if qdd is None else np.clip(
            checked_vector(qdd, self.limits.dof, "start acceleration"),
            -self.limits.acceleration, self.limits.acceleration)
        self._inp = ruckig_input(self.limits, position, velocity, acceleration)
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
        self._arrived_at_reset: np.ndarray | None = np.full(self.limits.dof, qd is None)
        zeros = np.zeros(self.limits.dof)
        self._setpoint = Setpoint(0, position, zeros if velocity is None else velocity,
                                  zeros if acceleration is None else acceleration)
        self._otg.reset()

    @property
    def setpoint(self) -> Setpoint:
        """The last setpoint returned (the start state before the first update)."""
        return self._setpoint

    def update(self, target: np.ndarray, now_ns: int,
               stream: tuple[np.ndarray, int] | None = None) -> Setpoint:
        """The setpoint for ``now_ns + control_period_ns``, following ``target``.

        ``stream`` is what the caller knows of the stream the target belongs to: the step into
        this target from the one before and the stream's own interval (an action grid). Without
        it, both are estimated from when targets change, which aliases when the stream's
        interval is not a multiple of the control period (10 ms actions on 4 ms ticks).

        Raises:
            ValueError: ``target`` is malformed or outside the position limits, or ``now_ns``
                went backwards.
        """
        goal = checked_position(target, self.limits, "interpolator target")
        if self._last_t_ns is not None and now_ns < self._last_t_ns:
            raise ValueError(f"time went backwards: {now_ns} < {self._last_t_ns}")
        self._last_t_ns = now_ns
        if goal.tobytes() != self._target.tobytes():  # exact change, cheaper than array_equal
            self._new_stream_sample(goal, now_ns, stream)
        elif self._stream_is_stale(now_ns):
            self._settle(self._arrived())
        self._advance()
        return self._setpoint

    def _new_stream_sample(self, goal: np.ndarray, now_ns: int,
                           stream: tuple[np.ndarray, int] | None) -> None:
        if stream is not None:
            step, interval = np.asarray(stream[0], dtype=float), stream[1]
        else:
            step = goal - self._target
            interval = None if self._target_t_ns is None else now_ns - self._target_t_ns
        if interval is not None and not 0 < interval <= self.config.max_stream_interval_ns:
            interval = None
        velocity = np.zeros(self.limits.dof)
        if interval is not None and self.config.velocity_feedforward:
            velocity = step / (interval * NS)
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

    def _arrived(self) -> np.ndarray:
        """Which joints have finished their profile (worked out only when a stream goes stale,
        not every tick)."""
        if self._arrived_at_reset is not None:
            return self._arrived_at_reset
        out = self._out
        return np.array(out.trajectory.independent_min_durations) <= out.time + 1e-12

    def _advance(self) -> None:
        result = self._step()
        if self._out.new_calculation:
            rejected = self._rejected_pass_through()
            if rejected.any():
                self._settle(rejected)
                result = self._step()
        if result not in OK_RESULTS:
            raise ValueError(f"interpolator could not plan from the current state ({result})")
        out = self._out
        self._arrived_at_reset = None
        self._setpoint = Setpoint(
            self._last_t_ns + self.config.control_period_ns, np.array(out.new_position),
            np.array(out.new_velocity), np.array(out.new_acceleration))
        out.pass_to_input(self._inp)

    def _step(self) -> Result:
        try:
            return self._otg.update(self._inp, self._out)
        except RuckigError as error:
            raise ValueError(f"interpolator input rejected: {ruckig_message(error)}") from None

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
