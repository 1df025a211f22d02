"""The gripper as one more CiA 402 drive on the arm's bus, in CSP, whose position is the opening.

This is how a CANopen cell usually carries an electric parallel gripper: a drive of its own,
brought up, cycled and supervised exactly like a joint drive (the driver treats it as one more
node for NMT, PDOs, the 402 state machine, heartbeat and EMCY), but with its own units (metres of
opening, :class:`~drivers.canopen402.units.GripperScale`) and its own rules for HOLD and STOP:

- each cycle's target is ``Command.gripper``, clipped to the stroke; ``None`` keeps the last one;
- HOLD and STOP never open it: the target becomes ``min(target, actual)``. A closing or squeezing
  gripper keeps its target (holding the drive at the position it has reached would take away the
  squeeze, and the part could slip out), an opening one stops where it is;
- STOP does not quick-stop it (see ``keep``), and its following error is not supervised, since
  a grasp holds the fingers off their target for as long as it holds the part.
- deactivate and aclose disable it with the joints: de-energised is every drive's safe state
  when the runtime lets go of the arm, and a grasp outlasts that only on a self-locking
  gripper. activate starts from where the fingers are (target := actual), so a grasp held
  across deactivate and activate squeezes again only once a command closes it.

``configure`` blocks (SDO, device thread); :class:`Gripper` only touches PDO buffers.
"""

from __future__ import annotations

import math

from drivers.base import ControlConfig
from drivers.canopen402 import bringup
from drivers.canopen402._sdk import Node402, PdoVariable
from drivers.canopen402.tables import Index
from drivers.canopen402.units import GRIPPER_STROKE_M, GripperScale

MAX_OPENING_M = GRIPPER_STROKE_M
NO_FOLLOWING_LIMIT = 0xFFFFFFFF
"""0x6065 value that switches following-error supervision off (CiA 402-2)."""


def configure(node: Node402, scale: GripperScale, control: ControlConfig) -> None:
    """Cycle parameters as the joints get, the stroke as software limits, and no
    following-error fault (device thread)."""
    bringup.write_cycle(node, control)
    bringup.write_limits(node, scale.to_counts(0.0), scale.to_counts(MAX_OPENING_M))
    node.sdo[Index.FOLLOWING_ERROR_WINDOW].raw = NO_FOLLOWING_LIMIT


class Gripper:
    """The cyclic side, once the PDOs are mapped: targets into the RPDO, opening from the TPDO."""

    def __init__(self, node: Node402, scale: GripperScale) -> None:
        self.node = node
        self.scale = scale
        self._target: PdoVariable = node.rpdo[1][Index.TARGET_POSITION]

    def start_here(self) -> None:
        """Target := actual before enabling, as for the joints: a CSP drive follows its target
        the moment it is enabled."""
        self._target.raw = self._actual()

    def command(self, opening_m: float | None) -> None:
        """Next cycle's target; None keeps the last one (the gripper stays as it is)."""
        if opening_m is None:
            return
        self._target.raw = self.scale.to_counts(min(max(opening_m, 0.0), MAX_OPENING_M))

    def keep(self) -> None:
        """HOLD or STOP: never open. The drive stays enabled: a quick-stopped gripper drive would
        hold its fingers where they are, which on a held part is no squeeze at all."""
        self._target.raw = min(int(self._target.raw), self._actual())

    def opening(self) -> float:
        """The measured opening in metres, from the latest TPDO."""
        return self.scale.to_m(self._actual())

    def _actual(self) -> int:
        return int(self.node.tpdo_values[Index.POSITION_ACTUAL])


def valid_opening(opening_m: float | None) -> bool:
    """None (keep) or a finite number; anything else is refused like a non-finite joint."""
    return opening_m is None or math.isfinite(opening_m)
