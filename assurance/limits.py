"""Joint limits of the robot, with a gripper dimension that projection leaves alone."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, slots=True, eq=False)
class JointLimits:
    """Position, velocity and acceleration limits per action dimension (rad, rad/s, rad/s²).

    ``lower``/``upper``/``velocity``/``acceleration`` have one entry per action dimension.
    Infinite entries mean "unbounded". ``gripper_index`` names the dimension that is a gripper
    command: it is excluded from divergence and from rate limits (a gripper event is a step).
    """

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    gripper_index: int | None = None
    gripper_event_threshold: float = 1e-3

    def __post_init__(self) -> None:
        n = self.lower.shape[0]
        for name in ("upper", "velocity", "acceleration"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"{name} has shape {getattr(self, name).shape}, expected ({n},)")
        if np.any(self.lower > self.upper):
            raise ValueError("a lower position limit exceeds its upper limit")
        if np.any(self.velocity <= 0) or np.any(self.acceleration <= 0):
            raise ValueError("velocity and acceleration limits must be positive")
        if self.gripper_index is not None and not 0 <= self.gripper_index < n:
            raise ValueError(f"gripper_index {self.gripper_index} outside 0..{n - 1}")
        for name in ("lower", "upper", "velocity", "acceleration"):
            getattr(self, name).setflags(write=False)
        mask = np.ones(n, dtype=bool)
        if self.gripper_index is not None:
            mask[self.gripper_index] = False
        mask.setflags(write=False)
        object.__setattr__(self, "_arm_mask", mask)

    @property
    def dim(self) -> int:
        return int(self.lower.shape[0])

    _arm_mask: np.ndarray = field(init=False, repr=False)

    @property
    def arm_mask(self) -> np.ndarray:
        """True for every dimension that is a joint (not the gripper); read-only."""
        return self._arm_mask

    def clip(self, q: np.ndarray) -> np.ndarray:
        return np.clip(q, self.lower, self.upper)

    @classmethod
    def uniform(
        cls, dim: int, position: float, velocity: float, acceleration: float, **kw: object
    ) -> JointLimits:
        """Symmetric limits, the same for every dimension (tests and examples)."""
        full = np.full(dim, 1.0)
        return cls(-position * full, position * full, velocity * full, acceleration * full, **kw)
