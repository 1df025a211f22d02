"""The core runtime: one object, fed events in time order, returning decisions and log lines.

``handle(event)`` for everything that happens; ``tick(t)`` once per control period. Both return
the decision-log lines they produced (the live shell also uses the tick's command). Events must
come in non-decreasing time; the core never reads a clock of its own.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from kernel.core import authority
from kernel.core.admit import admit
from kernel.core.config import CoreConfig
from kernel.core.events import (
    ChunkEvent,
    ClockSyncEvent,
    ControllerEvent,
    Event,
    ForceEvent,
    HandshakeEvent,
    LinkEvent,
    ObservationEvent,
    OodEvent,
    OperatorEvent,
    PhaseEvent,
    StateEvent,
    TickEvent,
)
from kernel.core.lines import Line
from kernel.core.state import CoreState
from kernel.core.tick import TickCommand, tick


class TimeWentBackwards(ValueError):
    """An event older than the last one: the caller's clock or journal is broken."""


_HANDLERS: dict[type, Callable[[CoreState, Any], None]] = {
    StateEvent: authority.on_state,
    ObservationEvent: authority.on_observation,
    PhaseEvent: authority.on_phase,
    ForceEvent: authority.on_force,
    OodEvent: authority.on_ood,
    LinkEvent: authority.on_link,
    HandshakeEvent: authority.on_handshake,
    OperatorEvent: authority.on_operator,
    ControllerEvent: authority.on_controller,
    ClockSyncEvent: authority.on_clock_sync,
    ChunkEvent: lambda state, event: admit(state, event.chunk),
}


class Core:
    def __init__(self, config: CoreConfig) -> None:
        self.config = config
        self.state = CoreState.initial(config)
        self.last_command: TickCommand | None = None

    def handle(self, event: Event) -> list[Line]:
        """Apply one event; a :class:`TickEvent` runs a control tick."""
        self._advance(event.t)
        if isinstance(event, TickEvent):
            self.last_command = tick(self.state)
        else:
            _HANDLERS[type(event)](self.state, event)
        return self._drain()

    def tick(self, t: int) -> tuple[TickCommand, list[Line]]:
        self._advance(t)
        command = tick(self.state)
        self.last_command = command
        return command, self._drain()

    def _advance(self, t: int) -> None:
        if t < self.state.t:
            raise TimeWentBackwards(f"event at {t} ns after {self.state.t} ns")
        self.state.t = t

    def _drain(self) -> list[Line]:
        lines, self.state.lines = self.state.lines, []
        return lines
