"""Ways back to work after a human takeover, one rule each, on the core alone (no cell, no
socket, no root): the operator's commands reach the core as ``OperatorEvent`` whoever sent them
(the socket's authority check is the shell's, tests/cell/test_operator.py).

- VALIDATE resumes the task's phase only with every joint measured inside its position limits
  (the fallback is RUNNING again from the accepted recovery on; the task holds in VALIDATE).
- A link lost during the takeover ends its session: accepting recovery then waits for a new
  handshake (DEGRADED) instead of returning to RUNNING on the dead session.
- The device's own e-stop is E_STOP (not a controller stop), and no reset leaves it while the
  device still asserts it.
"""

from __future__ import annotations

import numpy as np
import pytest

from assurance.fallback import Mode
from kernel.core.events import (
    ControllerEvent,
    ControllerStatus,
    Event,
    HandshakeEvent,
    LinkEvent,
    LinkStatus,
    OperatorAction,
    OperatorEvent,
    StateEvent,
)
from kernel.core.runtime import Core
from skills.phases import TaskPhase
from tests.runtime.machine_setup import core_config, feed, tick
from tools.scenarios.base import offer

MS = 1_000_000


class Cell:
    """A core in FREE_SPACE with a session, driven one event per millisecond, each followed by
    a control tick."""

    def __init__(self) -> None:
        self.config = core_config("FREE_SPACE")
        self.core = Core(self.config)
        self.t_ms = 0
        self.q = np.asarray(self.config.initial_q, dtype=float)
        self.send(HandshakeEvent(t=0, offer=offer()))
        assert self.mode is Mode.RUNNING and self.core.inspect_state().session is not None

    def send(self, event: Event) -> None:
        feed(self.core, event)
        tick(self.core, self.t_ms * MS + MS // 2)
        self.t_ms += 1

    def at(self) -> int:
        return self.t_ms * MS

    def operator(self, action: OperatorAction) -> None:
        self.send(OperatorEvent(t=self.at(), action=action))

    def measured(self, q: np.ndarray) -> None:
        self.q = np.asarray(q, dtype=float)
        self.send(StateEvent(t=self.at(), q=tuple(self.q.tolist())))

    def walk(self, q: np.ndarray, step_rad: float = 0.002) -> None:
        """The arm moved to ``q`` as an arm can (2 mrad a millisecond: a reading that jumps
        there at once is implausible, STATE_IMPLAUSIBLE, and never believed)."""
        start = self.q
        steps = max(1, int(np.ceil(np.max(np.abs(q - start)) / step_rad)))
        for i in range(1, steps + 1):
            self.measured(start + (q - start) * (i / steps))

    @property
    def mode(self) -> Mode:
        return self.core.status().mode

    @property
    def phase(self) -> TaskPhase:
        return self.core.status().phase


@pytest.mark.parametrize("side", ["above the upper", "below the lower"])
def test_validate_does_not_resume_with_a_joint_outside_its_limits(side: str) -> None:
    cell = Cell()
    limits = cell.config.limits
    above = side.startswith("above")
    outside = limits.clip(cell.config.initial_q)
    outside[2] = limits.upper[2] + 0.001 if above else limits.lower[2] - 0.001
    inside = outside.copy()  # a plausible step back across the limit
    inside[2] = limits.upper[2] - 0.001 if above else limits.lower[2] + 0.001
    cell.operator(OperatorAction.TAKEOVER)
    cell.walk(outside)  # the human left joint 2 beyond its limit
    cell.operator(OperatorAction.RELEASE)
    cell.operator(OperatorAction.ACCEPT_RECOVERY)
    for _ in range(5):  # ticks re-check; none may resume
        assert cell.phase is TaskPhase.VALIDATE
        cell.measured(outside)
    cell.measured(inside)  # back inside: the next check resumes the phase
    assert cell.mode is Mode.RUNNING and cell.phase is TaskPhase.FREE_SPACE


def test_a_link_lost_during_a_takeover_ends_its_session() -> None:
    cell = Cell()
    cell.operator(OperatorAction.TAKEOVER)
    cell.send(LinkEvent(t=cell.at(), status=LinkStatus.DOWN))
    assert cell.core.inspect_state().session is None
    cell.operator(OperatorAction.RELEASE)
    cell.operator(OperatorAction.ACCEPT_RECOVERY)
    # no session to resume on: wait for a handshake, never RUNNING on the dead session
    assert cell.mode is Mode.DEGRADED and cell.phase is TaskPhase.VALIDATE
    cell.send(HandshakeEvent(t=cell.at(), offer=offer()))
    assert cell.mode is Mode.RUNNING and cell.phase is TaskPhase.FREE_SPACE


def test_a_device_estop_is_e_stop_and_holds_until_the_device_clears_it() -> None:
    cell = Cell()
    cell.send(ControllerEvent(t=cell.at(), status=ControllerStatus.ESTOP))
    assert cell.mode is Mode.E_STOP
    cell.operator(OperatorAction.RESET)
    assert cell.mode is Mode.E_STOP  # the device still asserts it
    cell.send(ControllerEvent(t=cell.at(), status=ControllerStatus.OK))
    cell.operator(OperatorAction.RESET)
    assert cell.mode is Mode.SAFE_HOLD
