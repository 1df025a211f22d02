"""One control period of a cell: measure, decide, write what the core decided, advance.

Order within a tick, the same in lockstep and in wall-clock runs:
1. read the driver; a new sample becomes a ``state`` event (with the force residual);
2. a driver fault reaches the core once, as a ``controller`` event, and a failed run record
   (journal, decision log) once, as a ``recorder`` event: the core stops the arm, and the run
   ends after this tick (:attr:`ControlLoop.record_failed`);
3. the operator stand-in (simulation only) and the task may add events: operator actions,
   phase requests, classical moves, the gripper, the contact owner's descent;
4. the core's tick decides the one motion effect of the period;
5. the effect goes to the driver as its command; the command and the driver's answer are
   journaled; a command the device refused reaches the core as a ``controller`` event;
6. the world advances one period (in-process physics only).
The loop decides nothing itself: everything that shapes the command is the core's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from assurance.fallback import Owner
from assurance.reasons import ReasonCode
from drivers.base import Applied, Command, CommandKind, DriverError, DriverState, StateSample
from drivers.lifecycle import ManagedDriver
from kernel.app.device import World
from kernel.core.effects import Hold, Motion, Setpoint, Stop
from kernel.core.events import (
    ControllerEvent,
    ControllerStatus,
    Event,
    GripperEvent,
    InsertEvent,
    MoveEvent,
    PhaseEvent,
    RecorderEvent,
    StateEvent,
)
from kernel.journal import AppliedRecord, CommandOrigin
from kernel.shell.gateway import CoreGateway
from kernel.summary import CycleResult
from skills.assembly import (
    AssemblyRunner,
    GripperRequest,
    MoveRequest,
    PhaseRequest,
    Request,
    Sensed,
)

CycleDone = Callable[[CycleResult], None]
AT_REST_RAD_S = 0.02


@dataclass
class LoopCounters:
    ticks: int = 0
    refused_writes: int = 0
    driver_faults: list[str] = field(default_factory=list)


class ControlLoop:
    def __init__(
        self, gateway: CoreGateway, driver: ManagedDriver, world: World,
        runner: AssemblyRunner, operator: Any, cycles: int, on_cycle: CycleDone | None = None,
    ) -> None:
        self.gateway, self.driver, self.world = gateway, driver, world
        self.runner, self.operator = runner, operator
        self.cycles = cycles
        self.results: list[CycleResult] = []
        self.on_cycle = on_cycle
        self.counters = LoopCounters()
        self._last_seq = -1
        self._last_q: np.ndarray | None = None
        self._fault_reported = False
        self.record_failed = False
        """The recorder failed and the core was told: the run ends after this tick."""
        self._refusing = False
        self._cycle_started_ns = 0
        self._started = False
        self.cut: CycleResult | None = None
        """The cycle the run's end cut short, if one was under way (:meth:`cut_short`)."""

    @property
    def finished(self) -> bool:
        return len(self.results) >= self.cycles

    def start(self) -> None:
        self._started = True
        self._cycle_started_ns = self.gateway.now_ns()
        self.runner.begin(self._cycle_started_ns)

    def cut_short(self, reason: str) -> None:
        """The run ends with a cycle under way (interrupted, out of time, its record failed):
        that cycle was attempted and is not verified; ``reason`` says why it did not finish."""
        if not self._started or self.finished:
            return
        result = CycleResult(
            index=len(self.results) + 1, verified=False, depth_m=None,
            duration_s=round((self.gateway.now_ns() - self._cycle_started_ns) * 1e-9, 3),
            reason=reason)
        self.cut = result
        self.results.append(result)
        if self.on_cycle is not None:
            self.on_cycle(result)

    async def tick(self, skipped: int = 0) -> None:
        """One period (``skipped``: periods the timer saw pass without a tick just before)."""
        sample = await self._read()
        # Stamp after the read: while it awaited, the policy link may have fed the core a
        # later event, and the core only ever moves forward in time. Everything from here to
        # the write is synchronous, so the whole decision of this period shares one instant.
        t = self.gateway.now_ns()
        try:
            motion = self._decide(sample, t, skipped)
        except Exception:
            # A software fault never leaves the last command live: stop the device, then let
            # the error end the run (the supervisor reports it).
            stop = Stop(gripper=None, owner=Owner.SAFETY, reason=ReasonCode.CONTROLLER_FAULT)
            self.gateway.record_command(t, stop, await self._write(stop),
                                        origin=CommandOrigin.SHELL)
            raise
        if motion is None:
            return  # the run is over (the gateway is closed)
        applied = await self._write(motion)
        self.gateway.record_command(t, motion, applied)
        self._answer(t, applied)
        self.world.advance()
        self.counters.ticks += 1
        self._maybe_next_cycle(t)

    def _decide(self, sample: StateSample, t: int, skipped: int) -> Motion | None:
        """Sense, let the operator and the task speak, and ask the core for the command."""
        sensed = self._sense(sample, t)
        self._report_driver_fault(t)
        self._report_recorder_fault(t)
        active = self.driver.state is DriverState.ACTIVE
        if self.operator is not None:
            mode = self.gateway.status().mode
            for event in self.operator.observe(t, mode, _at_rest(sensed), active):
                self.gateway.feed(event)
        for request in self.runner.update(sensed, self.gateway.status()):
            self.gateway.feed(_event(request, t))
        return self.gateway.tick(t, skipped)

    async def _read(self) -> StateSample:
        """A fresh sample, or (the driver just faulted) the last one, marked with the fault."""
        try:
            return await self.driver.read()
        except DriverError:
            return await self.driver.read()  # FAULT now: the lifecycle answers from its record

    async def _write(self, motion: Motion) -> AppliedRecord:
        """Send the command; a failing device is FAULT from now on, reported next tick."""
        try:
            applied = await self.driver.write(driver_command(motion))
        except DriverError as error:
            return AppliedRecord(accepted=False, reason=error.reason)
        return _journaled(applied)

    def _answer(self, t: int, applied: AppliedRecord) -> None:
        """A command the device itself refused is an event for the core (CONTROLLER_REJECT →
        CONTROLLER_STOP); the first one it accepts again reports the controller healthy."""
        if applied.accepted:
            if self._refusing:
                self._refusing = False
                self.gateway.feed(ControllerEvent(t=t, status=ControllerStatus.OK))
            return
        self.counters.refused_writes += 1
        if self.driver.state is DriverState.ACTIVE and not self._refusing:
            self._refusing = True
            self.gateway.feed(ControllerEvent(t=t, status=ControllerStatus.REJECT,
                                              reason=applied.reason))

    def _sense(self, sample: StateSample, t: int) -> Sensed:
        fresh = sample.seq != self._last_seq and bool(sample.q) and not sample.faults
        q = np.array(sample.q) if sample.q else self._last_q
        if q is None:
            q = self.gateway.core.config.initial_q[self.gateway.core.config.limits.arm_mask]
        self._last_q = q
        qd = np.array(sample.qd) if sample.qd else np.zeros_like(q)
        wrench = np.array(sample.wrench) if sample.wrench else np.zeros(6)
        force = float(np.linalg.norm(wrench[:3]))
        if fresh:
            self._last_seq = sample.seq
            self.gateway.feed(StateEvent(t=t, q=tuple(q.tolist()), qd=tuple(qd.tolist()),
                                         force_residual=force))
            self.gateway.observe_robot(q, qd, wrench, sample.gripper, t)
        return Sensed(t_ns=t, q=q, qd=qd, force_norm=force, fresh=fresh,
                      driver_ok=self.driver.state is DriverState.ACTIVE)

    def _report_driver_fault(self, t: int) -> None:
        """A driver fault reaches the core once: e-stop as E_STOP, anything else as a fault."""
        if self.driver.state is not DriverState.FAULT or self._fault_reported:
            return
        self._fault_reported = True
        reason = self.driver.fault
        self.counters.driver_faults.append(f"{reason}: {self.driver.fault_detail}")
        status = ControllerStatus.ESTOP if reason is ReasonCode.E_STOP else ControllerStatus.FAULT
        self.gateway.feed(ControllerEvent(t=t, status=status, reason=reason))

    def _report_recorder_fault(self, t: int) -> None:
        """A run record that cannot be written reaches the core once (RECORDER_FAILED): its
        stop is this tick's command, the last the run sends before it ends."""
        recorder = self.gateway.recorder
        if self.record_failed or recorder is None or recorder.fault is None:
            return
        self.record_failed = True
        self.gateway.feed(RecorderEvent(t=t, fault=recorder.fault))

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
            self.world.feed_part()
            self._cycle_started_ns = t
            self.runner.begin(t)


def driver_command(motion: Motion) -> Command:
    """The driver's command for a motion effect (a translation, nothing decided here)."""
    if isinstance(motion, Stop):
        return Command(kind=CommandKind.STOP, gripper=motion.gripper)
    if isinstance(motion, Hold):
        return Command(kind=CommandKind.HOLD, gripper=motion.gripper)
    kind = CommandKind.IMPEDANCE if motion.stiffness else CommandKind.POSITION
    return Command(kind=kind, q=motion.q, stiffness=motion.stiffness, damping=motion.damping,
                   gripper=motion.gripper)


def _journaled(applied: Applied) -> AppliedRecord:
    return AppliedRecord(accepted=applied.accepted, reason=applied.reason,
                            t_device_ns=applied.t_mono_ns)


def _event(request: Request, t: int) -> Event:
    if isinstance(request, PhaseRequest):
        return PhaseEvent(t=t, to=request.to, evidence=request.evidence)
    if isinstance(request, MoveRequest):
        return MoveEvent(t=t, move_id=request.move_id, target=tuple(request.target.tolist()))
    if isinstance(request, GripperRequest):
        return GripperEvent(t=t, opening=request.opening)
    return InsertEvent(t=t, xy=(float(request.xy[0]), float(request.xy[1])),
                       z_end=request.z_end, rotation=tuple(request.rotation.ravel().tolist()))


def _at_rest(s: Sensed) -> bool:
    return float(np.abs(s.qd).max()) < AT_REST_RAD_S


__all__ = ["ControlLoop", "Setpoint", "driver_command"]
