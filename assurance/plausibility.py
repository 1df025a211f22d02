"""Is a measured state sample physically plausible? (docs/contract.md §8, STATE_IMPLAUSIBLE)

A joint reading is judged before the core acts on it, against what the arm can have done
since the last sample that was plausible:

- a reported velocity past ``velocity_factor`` times its limit is no motion of this arm;
- a position no joint can reach at its velocity limit in the time since that sample (the
  sample timestamps, not the nominal period) is a step no joint can make;
- where the device reports velocities, the position must also follow their integral: from
  the last plausible position, each interval adds the mean of its two reported velocities
  times its length, and a joint whose acceleration stays inside ``acceleration_factor`` times
  its limit cannot leave that path by more than a·dt²/4 per interval. A reading 0.5 rad off
  while the device says the joint turns at 0.2 rad/s fails this for as long as it lasts,
  where the velocity bound alone would accept it after 0.5 rad / v_max.

Noise and timing are tolerated explicitly: ``position_rad`` (encoder resolution, two
quantised readings), ``velocity_rad_s`` (velocity resolution and lag, integrated over the
time since the last plausible sample), and a sample that may be up to ``jitter_ns`` older than
its stamp says (a device cycle plus read latency), at the velocity it reported. A reading
repeated bit for bit while the device reports the joints moving (the driver read again before
the device's next frame came) is not new: it keeps the verdict of the sample it repeats, and
its later stamp moves nothing. The gripper
dimension is never judged here: its opening is not a joint of the arm.

Pure: times are arguments; the limits are the robot's own (the core's configuration).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import StrEnum

import numpy as np

from assurance.limits import JointLimits

NS = 1e-9


@dataclass(frozen=True, slots=True)
class Tolerances:
    """How much noise and timing slack a plausible sample may carry (the defaults suit the
    shipped drivers: a Dynamixel tick is 1.5 mrad, its velocity unit 0.024 rad/s)."""

    position_rad: float = 5e-3
    velocity_rad_s: float = 0.05
    velocity_factor: float = 2.0
    """A reported speed up to this multiple of the joint's limit (plus the velocity noise) is
    still a motion; beyond it, not (a push, an impact, tracking overshoot stay well below)."""
    acceleration_factor: float = 4.0
    """The same for the acceleration the position and velocity readings imply together: the
    limits are what warden commands, contact and impacts may briefly exceed them."""
    jitter_periods: float = 2.0
    jitter_s: float = 0.01
    """A sample may be this many control periods, or this many seconds if more, older than
    its stamp when it is first read (a device cycle, a receive thread that ran late)."""

    def __post_init__(self) -> None:
        for name in ("position_rad", "velocity_rad_s", "velocity_factor",
                     "acceleration_factor", "jitter_periods", "jitter_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"plausibility {name} must be positive and finite, got {value}")


@dataclass(frozen=True, slots=True, eq=False)
class Bounds:
    """The arm's joints' bounds for one core, computed once from its limits."""

    velocity: np.ndarray
    """rad/s per arm joint: the fastest reading that is still a motion."""
    acceleration: np.ndarray
    """rad/s² per arm joint, with the tolerance factor applied."""
    position_noise: float
    velocity_noise: float
    jitter_s: float

    @classmethod
    def of(cls, limits: JointLimits, period_ns: int,
           tolerances: Tolerances | None = None) -> Bounds:
        tol = tolerances or Tolerances()
        arm = limits.arm_mask
        return cls(velocity=limits.velocity[arm] * tol.velocity_factor,
                   acceleration=limits.acceleration[arm] * tol.acceleration_factor,
                   position_noise=tol.position_rad, velocity_noise=tol.velocity_rad_s,
                   jitter_s=max(tol.jitter_periods * period_ns * NS, tol.jitter_s))


class Breach(StrEnum):
    VELOCITY = "velocity"
    """The reported velocity is past its limit."""
    STEP = "step"
    """The position moved further than the velocity limit allows since the last plausible
    sample."""
    PATH = "path"
    """The position left the path the reported velocities integrate to."""


@dataclass(frozen=True, slots=True)
class Finding:
    breach: Breach
    joint: int
    """Index among the arm's joints (the gripper left out)."""
    value: float
    bound: float

    def describe(self) -> str:
        what = {
            Breach.VELOCITY: "reported velocity {v:.3f} rad/s past the plausible {b:.3f}",
            Breach.STEP: "position {v:.3f} rad from the last plausible sample, a joint can "
                         "move {b:.3f} rad in that time",
            Breach.PATH: "position {v:.3f} rad off the path its reported velocities allow "
                         "(bound {b:.3f} rad)",
        }[self.breach]
        return f"joint {self.joint}: " + what.format(v=self.value, b=self.bound)


@dataclass(frozen=True, slots=True, eq=False)
class Track:
    """What the next judgement needs: the last plausible sample (the anchor), the previous
    sample of any kind, and the reported velocities integrated from the anchor to it."""

    anchor_t: int
    anchor_q: np.ndarray
    anchor_u: float
    """How much earlier than its stamp the anchor may have been measured (s)."""
    last_t: int
    last_qd: np.ndarray | None
    predicted: np.ndarray | None
    """The anchor's position plus the integral of the reported velocities since; None when a
    sample on the way reported none."""
    drift: np.ndarray
    """The integral's tolerance so far: a·dt²/4 per interval."""
    last_q: np.ndarray | None = None
    last_finding: Finding | None = None
    """The previous sample's reading and verdict: a repeat of it gets the same verdict."""


@dataclass(frozen=True, slots=True, eq=False)
class PlausibilityVerdict:
    track: Track | None
    """What the next judgement starts from (None: no plausible sample yet)."""
    finding: Finding | None

    @property
    def plausible(self) -> bool:
        return self.finding is None


def judge(track: Track | None, t: int, q: np.ndarray, qd: np.ndarray | None,
          bounds: Bounds) -> PlausibilityVerdict:
    """Judge the arm's joints ``q`` (and reported velocities ``qd``, if any) sampled at ``t``.

    A plausible sample becomes the new anchor; an implausible one only carries the integral
    on, so that the readings after it are judged against the last plausible one. A velocity
    past its limit ends the integral (it would carry the path away): until the next plausible
    sample, positions are judged by the velocity limit alone.
    """
    if track is not None and _repeats(track, q, qd):
        return PlausibilityVerdict(track, track.last_finding)
    finding = _velocity_breach(qd, bounds)
    if track is None:
        return PlausibilityVerdict(
            _anchored(t, q, qd, bounds.jitter_s) if finding is None else None, finding)
    # Measured at most this long before its stamp: within its read, which began after the
    # sample before was stamped (a loaded machine's read can take tens of milliseconds).
    late = max(bounds.jitter_s, (t - track.last_t) * NS)
    advanced = _advance(track, t, qd if finding is None else None, bounds)
    finding = finding or _step_breach(track, t, q, bounds) or _path_breach(
        track, advanced, q, qd, late, bounds)
    if finding is None:
        return PlausibilityVerdict(_anchored(t, q, qd, late), None)
    return PlausibilityVerdict(replace(advanced, last_q=q.copy(), last_finding=finding), finding)


def _repeats(track: Track, q: np.ndarray, qd: np.ndarray | None) -> bool:
    """The same reading again, bit for bit, of a joint the device says is moving: a driver
    that read before the device's next frame came. It says nothing new, and its stamp is not
    when it was measured. (An arm at rest reads the same again and again, and each of those
    is a measurement.)"""
    if qd is None or track.last_q is None or track.last_qd is None:
        return False
    return bool(np.any(qd != 0.0) and np.array_equal(q, track.last_q)
                and np.array_equal(qd, track.last_qd))


def _anchored(t: int, q: np.ndarray, qd: np.ndarray | None, late: float) -> Track:
    return Track(anchor_t=t, anchor_q=q.copy(), anchor_u=late, last_t=t, last_qd=qd,
                 predicted=q.copy(), drift=np.zeros_like(q), last_q=q.copy())


def _velocity_breach(qd: np.ndarray | None, bounds: Bounds) -> Finding | None:
    if qd is None:
        return None
    limit = bounds.velocity + bounds.velocity_noise
    return _first(Breach.VELOCITY, np.abs(qd), limit)


def _step_breach(track: Track, t: int, q: np.ndarray, bounds: Bounds) -> Finding | None:
    elapsed = (t - track.anchor_t) * NS + track.anchor_u
    reach = bounds.position_noise + bounds.velocity * elapsed
    return _first(Breach.STEP, np.abs(q - track.anchor_q), reach)


def _advance(track: Track, t: int, qd: np.ndarray | None, bounds: Bounds) -> Track:
    """The integral carried on to ``t`` with the velocity reported now: over an interval the
    trapezoid of its two velocities is off by at most a·dt²/4 at acceleration a."""
    if qd is None or track.last_qd is None or track.predicted is None:
        return replace(track, last_t=t, last_qd=qd, predicted=None)
    dt = (t - track.last_t) * NS
    predicted = track.predicted + 0.5 * (track.last_qd + qd) * dt
    drift = track.drift + bounds.acceleration * dt * dt / 4.0
    return replace(track, last_t=t, last_qd=qd, predicted=predicted, drift=drift)


def _path_breach(track: Track, advanced: Track, q: np.ndarray, qd: np.ndarray | None,
                 late: float, bounds: Bounds) -> Finding | None:
    if advanced.predicted is None or qd is None or track.last_qd is None:
        return None
    elapsed = (advanced.last_t - advanced.anchor_t) * NS
    # The anchor and this sample were measured up to their own lateness before their stamps,
    # at about the speed they reported.
    speed = np.minimum(np.maximum(np.abs(qd), np.abs(track.last_qd)), bounds.velocity)
    allowed = (bounds.position_noise + advanced.drift + bounds.velocity_noise * elapsed
               + (speed + bounds.velocity_noise) * (track.anchor_u + late))
    return _first(Breach.PATH, np.abs(q - advanced.predicted), allowed)


def _first(breach: Breach, values: np.ndarray, limits: np.ndarray) -> Finding | None:
    over = np.flatnonzero(~(values <= limits))  # a NaN is over, too
    if over.size == 0:
        return None
    joint = int(over[0])
    return Finding(breach, joint, float(values[joint]), float(limits[joint]))
