"""The scripted insertion policy and its simulated inference latency.

A stand-in for a learned policy that behaves like one on the wire: it proposes joint-space
chunks conditioned on the observed joint state only (never on anything the robot did not
measure), moving toward a goal configuration fixed in the *server's* configuration at a bounded
joint speed, with seeded Gaussian noise. Inference takes a random time drawn from a lognormal
distribution given by its median and 95th percentile, as real GPU inference does (a fat right
tail).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

_Z95 = 1.6448536269514722  # standard normal quantile of 0.95


@dataclass(frozen=True, slots=True)
class LatencyModel:
    """Lognormal inference latency with the given median and p95 (milliseconds)."""

    median_ms: float = 5.0
    p95_ms: float = 10.0

    def __post_init__(self) -> None:
        if self.median_ms < 0 or self.p95_ms < self.median_ms:
            raise ValueError("need 0 <= median_ms <= p95_ms")

    def sample_s(self, rng: np.random.Generator) -> float:
        if self.median_ms == 0:
            return 0.0
        mu = math.log(self.median_ms)
        sigma = (math.log(self.p95_ms) - mu) / _Z95
        return float(rng.lognormal(mu, sigma)) / 1000.0


@dataclass(frozen=True, slots=True)
class InsertionPolicy:
    goal: np.ndarray
    max_speed: float
    """Joint speed bound, rad/s, per joint."""
    noise_std: float
    horizon: int
    action_dt_s: float
    max_acceleration: float | None = None
    """rad/s² per joint. None: the policy jumps to full speed at once, every joint on its own
    (a crude policy); set, all joints move together along a straight joint-space line,
    starting from the observed velocity and speeding up and braking smoothly, as a policy
    trained on smooth demonstrations does."""

    def __post_init__(self) -> None:
        if self.horizon <= 0 or self.action_dt_s <= 0 or self.max_speed <= 0:
            raise ValueError("horizon, action_dt and max_speed must be positive")
        if self.max_acceleration is not None and self.max_acceleration <= 0:
            raise ValueError("max_acceleration must be positive")

    def actions(self, q_obs: np.ndarray, lead_s: float, rng: np.random.Generator,
                qd_obs: np.ndarray | None = None) -> np.ndarray:
        """H x D actions; action j is due ``lead_s + j * action_dt_s`` after the observation.

        Each joint moves from the observed position toward the goal, never faster than
        ``max_speed``, and stays at the goal once there.
        """
        if q_obs.shape != self.goal.shape:
            raise ValueError(f"observed {q_obs.shape[0]} joints, the goal has {self.goal.shape[0]}")
        elapsed = lead_s + self.action_dt_s * np.arange(self.horizon)
        if self.max_acceleration is None:
            reach = self.max_speed * elapsed[:, None]
            path = q_obs + np.clip(self.goal - q_obs, -reach, reach)
        else:
            v0 = np.zeros_like(q_obs) if qd_obs is None else np.asarray(qd_obs, dtype=float)
            path = self._accelerated(q_obs, v0, elapsed)
        noise = rng.normal(0.0, self.noise_std, size=path.shape) if self.noise_std > 0 else 0.0
        return path + noise

    def _accelerated(self, q0: np.ndarray, v0: np.ndarray, times: np.ndarray) -> np.ndarray:
        """All joints together along the straight joint-space line to the goal, speeding up
        and braking within ``max_speed`` and ``max_acceleration`` for the joint that has
        furthest to go: the tool sweeps no arc past the goal on the way in."""
        span = self.goal - q0
        reach = float(np.abs(span).max())
        if reach < 1e-12:
            return np.broadcast_to(self.goal, (times.shape[0], q0.shape[0])).copy()
        direction = span / reach  # the furthest joint moves 1 rad per unit of progress
        vmax, a = self.max_speed, float(self.max_acceleration or 0.0)
        s, v, t = 0.0, float(np.clip(v0 @ direction / (direction @ direction), 0.0, vmax)), 0.0
        progress = np.empty(times.shape[0])
        for row, until in enumerate(times.tolist()):  # plain floats: numpy per scalar is slow
            while t < until - 1e-12:
                h = min(_SUBSTEP_S, until - t)
                wanted = min(vmax, math.sqrt(2.0 * a * max(reach - s, 0.0)))
                v = v + min(max(wanted - v, -a * h), a * h)
                s, t = min(s + v * h, reach), t + h
            progress[row] = s
        return q0 + progress[:, None] * direction


_SUBSTEP_S = 0.002
