"""The simulated operator of the simulated cell.

On a real cell a human accepts recovery. In simulation, so that ``warden run`` can show a
fallback and carry on, this stand-in does what a careful operator would: once the arm has come
to rest under the fallback owner it reports the controller healthy (if the driver says so) and
accepts recovery. It never resets an E_STOP: only a human may. Every action it takes goes
through the core as an ``operator`` event, so it is journaled and replayed like a human's.
"""

from __future__ import annotations

from dataclasses import dataclass

from assurance.fallback import Mode
from kernel.core.events import (
    ControllerEvent,
    ControllerStatus,
    Event,
    OperatorAction,
    OperatorEvent,
)

RECOVERABLE = frozenset({Mode.SAFE_HOLD, Mode.REPLAN_OR_RETREAT, Mode.CONTACT_FALLBACK,
                         Mode.HUMAN_RECOVERY, Mode.CONTROLLER_STOP})


@dataclass
class SimulatedOperator:
    enabled: bool = True
    patience_s: float = 0.5
    """How long the arm must be at rest under a fallback owner before recovery is accepted."""
    _since_ns: int | None = None
    recoveries: int = 0

    def observe(self, t_ns: int, mode: Mode, at_rest: bool, driver_ok: bool) -> list[Event]:
        if not self.enabled or mode not in RECOVERABLE or not at_rest:
            self._since_ns = None
            return []
        if self._since_ns is None:
            self._since_ns = t_ns
        if (t_ns - self._since_ns) * 1e-9 < self.patience_s:
            return []
        self._since_ns = None
        self.recoveries += 1
        events: list[Event] = []
        if mode is Mode.CONTROLLER_STOP:
            if not driver_ok:
                return []
            events.append(ControllerEvent(t=t_ns, status=ControllerStatus.OK))
        events.append(OperatorEvent(t=t_ns, action=OperatorAction.ACCEPT_RECOVERY))
        return events
