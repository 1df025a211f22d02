"""Where things are in an assembly cell: the nominal geometry the skills work with.

The skills never import a simulator: the cell that builds them passes its layout in (from
the robot model's constants in simulation, from calibration on a real cell).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, slots=True, eq=False)
class CellLayout:
    home_q: np.ndarray
    tool_down: np.ndarray
    """TCP orientation (3x3) for every tool-down pose of the cycle."""
    peg_start: np.ndarray
    """Peg centre where the feeder presents it."""
    hole_top: np.ndarray
    """Centre of the hole's opening on the fixture's top face."""
    peg_centre_below_tcp: float
    peg_half_height: float
    hole_depth: float
    gripper_open: float
    gripper_closed: float = 0.0
    clearance_height: float = 0.15
    """TCP height above a target for approach, lift and staging moves (m)."""
    pre_insert_gap: float = 0.005
    """Gap between the peg's bottom and the fixture top at the pre-insert pose (m)."""
    workspace_margin: np.ndarray = field(default_factory=lambda: np.array([0.05, 0.05, 0.05]))

    def tcp_above(self, point: np.ndarray, height: float) -> np.ndarray:
        return np.asarray(point, dtype=float) + np.array([0.0, 0.0, height])

    @property
    def grasp_tcp(self) -> np.ndarray:
        return self.tcp_above(self.peg_start, self.peg_centre_below_tcp)

    @property
    def pre_insert_tcp(self) -> np.ndarray:
        """TCP with the held peg's bottom ``pre_insert_gap`` above the hole's opening."""
        offset = self.peg_centre_below_tcp + self.peg_half_height + self.pre_insert_gap
        return self.tcp_above(self.hole_top, offset)

    @property
    def staging_tcp(self) -> np.ndarray:
        return self.tcp_above(self.hole_top, self.clearance_height)

    def insertion_depth_of(self, tcp_z: float) -> float:
        """How deep the held peg's bottom is below the opening, from the TCP height alone."""
        bottom = tcp_z - self.peg_centre_below_tcp - self.peg_half_height
        return max(0.0, float(self.hole_top[2] - bottom))
