"""The core runtime: one object, fed events in time order, returning what it decided.

``step(event)`` is the one entry point: a :class:`~kernel.core.events.TickEvent` once per
control period, every other event as it happens. It returns a :class:`~kernel.core.effects.Step`:
the decision-log lines the event produced and the effects the shell must carry out (on a tick,
exactly one motion effect: the command that reaches the arm). Events must come in
non-decreasing time; the core never reads a clock of its own.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import msgspec

from assurance.fallback import Mode
from assurance.reasons import ReasonCode
from assurance.rtc import Committed, committed_prefix
from kernel.core import authority
from kernel.core.admit import admit, on_computed
from kernel.core.cameras import on_camera
from kernel.core.config import CoreConfig
from kernel.core.effects import Step
from kernel.core.events import (
    CameraEvent,
    ChunkEvent,
    ClockSyncEvent,
    ComputedEvent,
    ControllerEvent,
    Event,
    ForceEvent,
    GripperEvent,
    HandshakeEvent,
    InsertEvent,
    LinkEvent,
    MoveEvent,
    ObservationEvent,
    OodEvent,
    OperatorEvent,
    PhaseEvent,
    RecorderEvent,
    StateEvent,
    TickEvent,
)
from kernel.core.state import CoreState
from kernel.core.tick import tick
from skills.contact import ContactState, DescentStatus
from skills.phases import TaskPhase
from skills.planner import MoveStatus
from skills.trajectory import MotionLimits


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
    ComputedEvent: lambda state, event: on_computed(state, event.result),
    MoveEvent: authority.on_move,
    GripperEvent: authority.on_gripper,
    InsertEvent: authority.on_insert,
    RecorderEvent: authority.on_recorder,
    CameraEvent: on_camera,
    TickEvent: lambda state, event: tick(state),
}


class CoreStatus(msgspec.Struct, frozen=True, kw_only=True):
    """What the shell may know of the core: a read-only copy, taken when asked. The task that
    sequences the core waits on it; the operator socket, the service status and a trial's
    bounds report from it."""

    phase: TaskPhase
    mode: Mode
    cause: ReasonCode | None
    """The trigger of the fallback mode the core is in (None while it runs undisturbed)."""
    epoch: int
    move_id: int
    move: MoveStatus
    contact: ContactState
    descent: DescentStatus = DescentStatus.NONE
    """What became of the last ``insert`` (its path checked, started, refused)."""
    parked: int
    """Chunks waiting for a job's result."""


class Core:
    """The core. Its state is private: the shell reads :meth:`status`, and changes it only by
    :meth:`step`, so every change is an event a journal records and a replay repeats."""

    def __init__(self, config: CoreConfig) -> None:
        self.config = config
        self._state = CoreState.initial(config)

    @property
    def planner_limits(self) -> MotionLimits:
        """The limits the core plans classical moves within (fixed by the configuration; the
        task's planner plans its approach with the same)."""
        return self._state.motion.planner_limits

    def step(self, event: Event) -> Step:
        """Apply one event; a :class:`TickEvent` runs a control tick.

        Raises:
            TimeWentBackwards: ``event`` is older than the last one.
        """
        state = self._state
        if event.t < state.t:
            raise TimeWentBackwards(f"event at {event.t} ns after {state.t} ns")
        state.t = event.t
        _HANDLERS[type(event)](state, event)
        step = Step(tuple(state.lines), tuple(state.effects), tuple(state.decisions))
        state.lines.clear()
        state.effects.clear()
        state.decisions.clear()
        return step

    def status(self) -> CoreStatus:
        state, motion = self._state, self._state.motion
        fallback = state.fallback
        return CoreStatus(phase=state.task.phase, mode=fallback.mode, cause=fallback.cause,
                          epoch=state.epoch, move_id=motion.move_id, move=motion.move_status,
                          contact=motion.contact.state, descent=motion.descent_status,
                          parked=len(state.parked))

    def committed(self, t: int, action_dt: int) -> Committed | None:
        """The queued actions in force at ``t``, ``t + action_dt``, ... (real-time chunking's
        prefix, :func:`assurance.rtc.committed_prefix`): a question about the future that
        changes nothing. None in a Cartesian session, whose policy acts in another space."""
        if self._state.config.cartesian is not None:
            return None
        return committed_prefix(self._state.queue, t, action_dt)

    def inspect_state(self) -> CoreState:
        """The live, mutable state, for tests and offline tools that check the core's inner
        workings (the queue's rows, the duplicate memory, the last setpoint): what no status
        should carry. Never for the shell (tests/runtime/test_core_status.py checks): a reader
        there would couple the shell to the core's internals, and a writer would change a
        decision without an event, which no journal records and no replay repeats."""
        return self._state
