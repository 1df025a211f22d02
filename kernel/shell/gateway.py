"""The one door to the core in a live run.

Everything that happens reaches the core through :meth:`CoreGateway.feed`, stamped with the
run's clock (nanoseconds since the run started, so journals replay with small exact numbers):
the control tick's state samples and ticks, the policy link's handshakes and chunks, operator
actions. Every fed event is journaled, every produced line is recorded and handed to the
listeners (the policy link wants the inference requests, the summary wants everything).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from assurance.handshake import ClientHello
from kernel.core.events import Event, TickEvent
from kernel.core.lines import Line
from kernel.core.runtime import Core
from kernel.core.tick import TickCommand
from kernel.shell.link_types import RobotSample
from kernel.shell.recorder import Recorder
from kernel.shell.timer import Clock

Listener = Callable[[list[Line]], None]


class CoreGateway:
    def __init__(self, core: Core, clock: Clock, recorder: Recorder | None = None) -> None:
        self.core = core
        self.clock = clock
        self.t0_ns = clock.now_ns()
        self.recorder = recorder
        self.listeners: list[Listener] = []
        self.robot = RobotSample(q=core.state.measured_q.copy(), task_phase=core.state.task.phase)
        self.closed = False

    def now_ns(self) -> int:
        return self.clock.now_ns() - self.t0_ns

    def close(self) -> None:
        """The run is over: nothing more is decided, journaled or reported (a link that says
        goodbye afterwards is not a fallback of the run)."""
        self.closed = True

    def feed(self, event: Event) -> list[Line]:
        if self.closed:
            return []
        lines = self.core.handle(event)
        if self.recorder is not None:
            self.recorder.event(event)
            self.recorder.lines(lines)
        for listener in self.listeners:
            listener(lines)
        return lines

    def tick(self, t_ns: int | None = None) -> TickCommand:
        self.feed(TickEvent(t=self.now_ns() if t_ns is None else t_ns))
        command = self.core.last_command
        if command is None:  # cannot happen: a TickEvent always produces a command
            raise RuntimeError("the core produced no tick command")
        return command

    def client_side_hello(self) -> ClientHello:
        return self.core.config.client.hello(self.core.state.epoch)

    def capture_observation(self) -> RobotSample:
        return self.robot

    def observe_robot(self, q: np.ndarray, qd: np.ndarray, wrench: np.ndarray,
                      gripper: float | None) -> None:
        """What the next observation will carry (the control tick updates it each period)."""
        self.robot = RobotSample(q=q, task_phase=str(self.core.state.task.phase), qd=qd,
                                 wrench=wrench, gripper=gripper)
