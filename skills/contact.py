"""The contact owner: a force-guarded compliant insertion and a force-aware retreat.

From contact onset this law owns motion (seed §2.2). It lowers the tool along the hole's axis
at a fixed speed in joint impedance mode, re-solving IK for the tool-down pose each tick, and
stops when the target depth is reached or the measured force says the peg has landed. A target
offered by an admitted chunk is only ever a bounded correction of its own nominal target: it
is clipped to ``max_target_offset`` and never replaces the law. The retreat lifts along the
same axis, compliantly, until the tool is back at the start height.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from assurance.kinematics import ArmKinematics, Pose


class ContactState(StrEnum):
    IDLE = "idle"
    HOLDING = "holding"
    DESCENDING = "descending"
    DWELLING = "dwelling"
    DONE = "done"
    RETREATING = "retreating"
    RETREATED = "retreated"


@dataclass(frozen=True, slots=True, eq=False)
class ContactConfig:
    speed_m_s: float = 0.03
    retreat_speed_m_s: float = 0.04
    stop_force_n: float = 12.0
    """Force (norm) at which the descent stops: the peg has landed."""
    dwell_s: float = 0.25
    max_target_offset: float = 0.002
    """Largest correction (rad per joint) a bounded target may add to the law's own target."""
    stiffness: np.ndarray = field(
        default_factory=lambda: np.array([1500.0, 1500.0, 1000.0, 200.0, 200.0, 200.0]))
    damping: np.ndarray = field(default_factory=lambda: 2 * np.sqrt(
        np.array([1500.0, 1500.0, 1000.0, 200.0, 200.0, 200.0])
        * np.array([2.0, 2.0, 0.6, 0.15, 0.15, 0.12])))


@dataclass(frozen=True, slots=True, eq=False)
class ContactCommand:
    q: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    state: ContactState


class ContactOwner:
    def __init__(self, kinematics: ArmKinematics, tool_down: np.ndarray,
                 config: ContactConfig | None = None) -> None:
        self.kin = kinematics
        self.tool_down = tool_down
        self.config = config or ContactConfig()
        self.state = ContactState.IDLE
        self._xy = np.zeros(2)
        self._z = self._z_start = self._z_end = 0.0
        self._q = np.zeros(kinematics.dof)
        self._dwell_until = 0

    def start(self, q: np.ndarray, xy: np.ndarray, z_start: float, z_end: float) -> None:
        """Begin a descent from ``z_start`` to ``z_end`` along the vertical through ``xy``."""
        self._xy, self._z, self._z_start, self._z_end = np.asarray(xy, float), z_start, \
            z_start, z_end
        self._q = np.asarray(q, dtype=float).copy()
        self.state = ContactState.DESCENDING

    def reset(self) -> None:
        """A new cycle: nothing to descend, hold or retreat from."""
        self.state = ContactState.IDLE

    def hold_at(self, q: np.ndarray) -> None:
        """Compliantly hold ``q`` (contact owned without a descent to run)."""
        self._q = np.asarray(q, dtype=float).copy()
        self.state = ContactState.HOLDING

    def begin_retreat(self, q: np.ndarray) -> None:
        """Force-aware retreat from wherever the tool is now back up to the start height."""
        if self.state in (ContactState.RETREATING, ContactState.RETREATED):
            return
        self._q = np.asarray(q, dtype=float).copy()
        position = self.kin.forward(self._q).position
        self._z = float(position[2])
        if self.state in (ContactState.IDLE, ContactState.HOLDING):
            self._z_start = self._z + 0.02
            self._xy = position[:2]
        self.state = ContactState.RETREATING

    def step(self, now_ns: int, dt_s: float, force_norm: float,
             bounded_target: np.ndarray | None = None) -> ContactCommand:
        cfg = self.config
        if self.state is ContactState.DESCENDING:
            self._descend(now_ns, dt_s, force_norm)
        elif self.state is ContactState.DWELLING and now_ns >= self._dwell_until:
            self.state = ContactState.DONE
        elif self.state is ContactState.RETREATING:
            self._z = min(self._z + cfg.retreat_speed_m_s * dt_s, self._z_start)
            if self._z >= self._z_start:
                self.state = ContactState.RETREATED
        if self.state in (ContactState.DESCENDING, ContactState.RETREATING):
            self._q = self._solve(self._z)
        target = self._q
        if bounded_target is not None:
            offset = np.clip(np.asarray(bounded_target) - self._q, -cfg.max_target_offset,
                             cfg.max_target_offset)
            target = self._q + offset
        return ContactCommand(target, cfg.stiffness, cfg.damping, self.state)

    def _descend(self, now_ns: int, dt_s: float, force_norm: float) -> None:
        landed = force_norm >= self.config.stop_force_n
        self._z = max(self._z - self.config.speed_m_s * dt_s, self._z_end)
        if landed or self._z <= self._z_end:
            self.state = ContactState.DWELLING
            self._dwell_until = now_ns + int(self.config.dwell_s * 1e9)

    def _solve(self, z: float) -> np.ndarray:
        target = Pose(np.array([self._xy[0], self._xy[1], z]), self.tool_down)
        return self.kin.solve(target, self._q).q
