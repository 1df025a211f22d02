"""One control period of the cell: measure, decide, command, advance.

Order within a tick, the same in lockstep and in wall-clock runs:
1. read the driver; a new sample becomes a ``state`` event (with the force residual);
2. the simulated operator and the cycle runner may add ``operator``/``phase`` events;
3. the core's tick decides who owns the period and where it may go;
4. the motion controller turns that into one driver command, written if the driver is active;
5. the world advances one period (in-process physics only).
A driver that faults is reported to the core once, as a ``controller`` event.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from assurance.fallback import Mode
from assurance.reasons import ReasonCode
from drivers.base import Applied, Command, CommandKind, DriverError, DriverState, StateSample
from drivers.lifecycle import ManagedDriver
from kernel.cell.motion import MotionController
from kernel.cell.operator import SimulatedOperator
from kernel.cell.world import World
from kernel.core.events import ControllerEvent, PhaseEvent, StateEvent
from kernel.shell.gateway import CoreGateway
from kernel.summary import CycleResult
from skills.assembly import AssemblyRunner, Sensed

CycleDone = Callable[[CycleResult], None]


@dataclass
class CellCounters:
    ticks: int = 0
    refused_writes: int = 0
    driver_faults: list[str] = field(default_factory=list)


class CellController:
    def __init__(
        self, gateway: CoreGateway, driver: ManagedDriver, world: World,
        runner: AssemblyRunner, motion: MotionController, operator: SimulatedOperator,
        cycles: int, on_cycle: CycleDone | None = None,
    ) -> None:
        self.gateway, self.driver, self.world = gateway, driver, world
        self.runner, self.motion, self.operator = runner, motion, operator
        self.cycles = cycles
        self.results: list[CycleResult] = []
        self.on_cycle = on_cycle
        self.counters = CellCounters()
        self._last_seq = -1
        self._fault_reported = False
        self._cycle_started_ns = 0

    @property
    def finished(self) -> bool:
        return len(self.results) >= self.cycles

    def start(self) -> None:
        self._cycle_started_ns = self.gateway.now_ns()
        self.runner.begin(self._cycle_started_ns)

    async def tick(self) -> None:
        sample = await self._read()
        # Stamp after the read: while it awaited, the policy link may have fed the core a
        # later event, and the core only ever moves forward in time. Everything from here to
        # the write is synchronous, so the whole decision of this period shares one instant.
        t = self.gateway.now_ns()
        try:
            command = self._decide(sample, t)
        except Exception:
            # A software fault never leaves the last command live: stop the device, then let
            # the error end the run (the supervisor reports it).
            await self._write(Command(kind=CommandKind.STOP, gripper=self.runner.gripper))
            raise
        applied = await self._write(command)
        self._count(applied)
        self.world.advance()
        self.counters.ticks += 1
        self._maybe_next_cycle(t)

    def _decide(self, sample: StateSample, t: int) -> Command:
        """Sense, let the operator and the cycle runner speak, ask the core, shape the command."""
        sensed = self._sense(sample, t)
        self._report_driver_fault(t)
        state = self.gateway.core.state
        for event in self.operator.observe(t, state.fallback.mode, self._at_rest(sensed),
                                           self.driver.state is DriverState.ACTIVE):
            self.gateway.feed(event)
        request = self.runner.update(sensed, state.task.phase, state.fallback.mode)
        if request is not None:
            self.gateway.feed(PhaseEvent(t=t, to=request.to, evidence=request.evidence))
        return self.motion.command(self.gateway.tick(t), sensed)

    async def _read(self) -> StateSample:
        """A fresh sample, or (the driver just faulted) the last one, marked with the fault."""
        try:
            return await self.driver.read()
        except DriverError:
            return await self.driver.read()  # FAULT now: the lifecycle answers from its record

    async def _write(self, command: Command) -> Applied | None:
        """Send the command; a failing device is FAULT from now on, reported next tick."""
        try:
            return await self.driver.write(command)
        except DriverError:
            return None

    def _sense(self, sample: StateSample, t: int) -> Sensed:
        fresh = sample.seq != self._last_seq and bool(sample.q) and not sample.faults
        q = np.array(sample.q) if sample.q else self.motion.commanded.copy()
        qd = np.array(sample.qd) if sample.qd else np.zeros_like(q)
        wrench = np.array(sample.wrench) if sample.wrench else np.zeros(6)
        force = float(np.linalg.norm(wrench[:3]))
        if fresh:
            self._last_seq = sample.seq
            self.gateway.feed(StateEvent(t=t, q=tuple(q.tolist()), qd=tuple(qd.tolist()),
                                         force_residual=force))
            self.gateway.observe_robot(q, qd, wrench, sample.gripper)
        return Sensed(t_ns=t, q=q, qd=qd, force_norm=force, fresh=fresh,
                      driver_ok=self.driver.state is DriverState.ACTIVE)

    def _report_driver_fault(self, t: int) -> None:
        """A driver fault reaches the core once: e-stop as E_STOP, anything else as a fault."""
        if self.driver.state is not DriverState.FAULT or self._fault_reported:
            return
        self._fault_reported = True
        reason = self.driver.fault
        self.counters.driver_faults.append(f"{reason}: {self.driver.fault_detail}")
        status = "estop" if reason is ReasonCode.E_STOP else "fault"
        self.gateway.feed(ControllerEvent(t=t, status=status))

    def _count(self, applied: Applied | None) -> None:
        if applied is None or not applied.accepted:
            self.counters.refused_writes += 1

    def _at_rest(self, s: Sensed) -> bool:
        return float(np.abs(s.qd).max()) < 0.02

    def _maybe_next_cycle(self, t: int) -> None:
        if not self.runner.done or self.finished:
            return
        outcome = self.runner.outcome
        result = CycleResult(
            index=len(self.results) + 1, verified=bool(outcome and outcome.verified),
            depth_m=round(outcome.depth_m if outcome else 0.0, 5),
            duration_s=round((t - self._cycle_started_ns) * 1e-9, 3),
            reason=outcome.reason if outcome else "no outcome",
        )
        self.results.append(result)
        if self.on_cycle is not None:
            self.on_cycle(result)
        if not self.finished:
            self.world.feed_peg()
            self._cycle_started_ns = t
            self.runner.begin(t)

    @property
    def mode(self) -> Mode:
        return self.gateway.core.state.fallback.mode
