"""The one door to the core in a live run.

Everything that happens reaches the core through :meth:`CoreGateway.feed`, stamped with the
run's clock (nanoseconds since the run started, so journals replay with small exact numbers):
the control tick's state samples and ticks, the policy link's handshakes and chunks, operator
actions, job results. Every fed event is journaled and every produced line recorded; the lines
go to the listeners (the run's summary), and each effect and decision record goes to the
handlers registered for its type (the policy link takes
:class:`~kernel.core.effects.RequestObservation`, :class:`~kernel.core.effects.EndSession` and
:class:`~kernel.core.effects.ChunkDecision`, the job runner takes
:class:`~kernel.core.effects.Compute`). An event a handler feeds waits until the step it
answers is handed out in full (no handler re-enters the core). The motion effect of a tick goes
back to the control loop, which writes it to the driver and journals what it wrote and what the
driver answered.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np

from assurance.handshake import ClientHello
from kernel.core.effects import DecisionRecord, Effect, Motion, Step
from kernel.core.events import Event, TickEvent
from kernel.core.lines import Line
from kernel.core.runtime import Core, CoreStatus
from kernel.journal import AppliedRecord, CommandOrigin, CommandRecord
from kernel.shell.link_types import RobotSample
from kernel.shell.recorder import Recorder
from kernel.shell.timer import Clock

Listener = Callable[[tuple[Line, ...]], None]
E = TypeVar("E", bound=Effect | DecisionRecord)
_NOTHING = Step((), ())


class CoreGateway:
    def __init__(self, core: Core, clock: Clock, recorder: Recorder | None = None) -> None:
        self.core = core
        self.clock = clock
        self.t0_ns = clock.now_ns()
        self.recorder = recorder
        self.listeners: list[Listener] = []
        self._handlers: dict[type, list[Callable[[Any], None]]] = {}
        # Before the first sample, the arm is where the configuration starts it (a gateway
        # opens on a core that has not stepped yet).
        self.robot = RobotSample(q=core.config.initial_q.copy(), task_phase=core.status().phase)
        self.closed = False
        self._feeding = False
        self._queued: deque[Event] = deque()

    def now_ns(self) -> int:
        return self.clock.now_ns() - self.t0_ns

    def close(self) -> None:
        """The run is over: nothing more is decided, journaled or reported (a link that says
        goodbye afterwards is not a fallback of the run)."""
        self.closed = True

    def on(self, kind: type[E], handler: Callable[[E], None]) -> None:
        """Call ``handler`` with every effect or decision record of type ``kind`` the core
        produces, whichever event produced it."""
        self._handlers.setdefault(kind, []).append(handler)

    def feed(self, event: Event) -> Step:
        """Step the core with ``event`` and hand out what it produced: the step's decisions
        and effects go to the handlers of their types, in the order they arose.

        A handler that feeds an event of its own (a job run inline, an observation taken) is
        not stepped into the core in the middle of the step it is answering: its event waits
        until every decision and effect of that step has been handed out, then is fed, in
        order; such a nested ``feed`` returns an empty step (no caller of one reads it).
        """
        if self._feeding:
            self._queued.append(event)
            return _NOTHING
        self._feeding = True
        try:
            step = self._step(event)
            while self._queued:
                self._step(self._queued.popleft())
        finally:
            self._feeding = False
            self._queued.clear()
        return step

    def _step(self, event: Event) -> Step:
        if self.closed:
            return _NOTHING
        step = self.core.step(event)
        if self.recorder is not None:
            self.recorder.event(event)
            self.recorder.lines(step.lines)
        for listener in self.listeners:
            listener(step.lines)
        for record in (*step.decisions, *step.effects):
            for handler in self._handlers.get(type(record), ()):
                handler(record)
        return step

    def tick(self, t_ns: int, skipped: int = 0) -> Motion | None:
        """Run the control tick at ``t_ns`` (``skipped``: periods the loop missed just before
        it): the command the core decided for the arm (None only once the run is over)."""
        return self.feed(TickEvent(t=t_ns, skipped=skipped)).motion

    def record_command(self, t_ns: int, effect: Motion, applied: AppliedRecord | None,
                       origin: CommandOrigin = CommandOrigin.CORE) -> None:
        """Journal what was written to the driver and what the driver answered."""
        if self.recorder is not None and not self.closed:
            self.recorder.command(CommandRecord(t=t_ns, effect=effect, applied=applied,
                                                origin=origin))

    def status(self) -> CoreStatus:
        return self.core.status()

    def client_side_hello(self) -> ClientHello:
        return self.core.config.client.hello(self.core.status().epoch)

    def capture_observation(self, prefix_grid_ns: int | None = None,
                            at_ns: int | None = None) -> RobotSample:
        """The robot as last measured; with ``prefix_grid_ns``, and the actions committed from
        ``at_ns`` (the observation's time; default now) on that grid."""
        if prefix_grid_ns is None:
            return self.robot
        at = self.now_ns() if at_ns is None else at_ns
        return dataclasses.replace(self.robot, committed=self.core.committed(at, prefix_grid_ns))

    def observe_robot(self, q: np.ndarray, qd: np.ndarray, wrench: np.ndarray,
                      gripper: float | None, t_ns: int | None = None) -> None:
        """What the next observation will carry (the control tick updates it each period;
        ``t_ns``: when it was measured, on the run's clock)."""
        self.robot = RobotSample(q=q, task_phase=str(self.core.status().phase), qd=qd,
                                 wrench=wrench, gripper=gripper, measured_ns=t_ns)
