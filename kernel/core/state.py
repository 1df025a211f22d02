"""The core's mutable state and the side effects every handler shares.

Handlers in :mod:`admit`, :mod:`authority` and :mod:`tick` change this state only through the
methods here when a change must also be logged (a fallback transition, a purge, a new epoch),
so a decision and its log line can never drift apart.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import msgspec
import numpy as np

from assurance.clock import ClockMap, ns_to_ms
from assurance.fallback import MODES, FallbackMachine, Mode, QueueAction, Transition
from assurance.gates import AdmissionContext
from assurance.handshake import Session
from assurance.identity import ChunkMemory, ObservationLog
from assurance.plausibility import Bounds, Track
from assurance.queue import ActionQueue, SentRow
from assurance.reasons import ReasonCode
from assurance.watermarks import Watermarks
from kernel.core.config import CoreConfig
from kernel.core.descent import drop_descent
from kernel.core.effects import Compute, DecisionRecord, Effect, EndSession
from kernel.core.jobs import ClearanceJob
from kernel.core.lines import Line, Machine, QueueLine, TransitionLine
from kernel.core.lines import QueueAction as QueueAct
from kernel.core.motion_state import MotionState, initial_motion
from skills.phases import PhaseCard, TaskPhase
from skills.task_fsm import TaskDecision, TaskMachine


@dataclass(slots=True, eq=False)
class CoreState:
    config: CoreConfig
    task: TaskMachine
    fallback: FallbackMachine
    session: Session | None
    epoch: int
    measured_q: np.ndarray
    clock: ClockMap
    motion: MotionState
    t: int = 0
    link_up: bool = True
    last_sequence: int | None = None
    measured_t: int | None = None
    watched_since: int | None = None
    """The first tick's time: the state watchdog counts from here until a sample arrives."""
    hold_q: np.ndarray | None = None
    last_setpoint: SentRow | None = None
    """The queued row the last tick sent as a policy setpoint; None after any other tick. A
    chunk admitted before the next tick is projected from it even if the queue was purged
    since (a new epoch), so the stream of sent setpoints stays inside the limits."""
    last_tick: int | None = None
    """When the last control tick ran (the next is due a period later)."""
    underrun_since: int | None = None
    executed_in_epoch: bool = False
    controller_ok: bool = True
    estop_asserted: bool = False
    queue: ActionQueue = field(default_factory=ActionQueue)
    memory: ChunkMemory = field(default_factory=ChunkMemory)
    observations: ObservationLog = field(default_factory=ObservationLog)
    watermarks: Watermarks | None = None
    lines: list[Line] = field(default_factory=list)
    effects: list[Effect] = field(default_factory=list)
    decisions: list[DecisionRecord] = field(default_factory=list)
    parked: dict[int, Any] = field(default_factory=dict)
    """Chunks waiting for a job's result, by job id (see :mod:`kernel.core.admit`)."""
    jobs_issued: int = 0
    queue_version: int = 0
    """Counts the admissions and purges that changed the queue: a real-time chunking prefix
    taken at another version is not what runs now (:mod:`assurance.rtc`)."""
    plausible: Track | None = None
    """The last plausible state sample and what followed it (:mod:`assurance.plausibility`)."""
    plausibility: Bounds | None = None
    cameras_down: dict[str, int] = field(default_factory=dict)
    """Cameras lost or frozen, and since when (:mod:`kernel.core.cameras`)."""

    @classmethod
    def initial(cls, config: CoreConfig) -> CoreState:
        state = cls(
            config=config, task=TaskMachine(config.initial_phase),
            fallback=FallbackMachine(config.degrade_after), session=config.initial_session,
            epoch=config.initial_epoch, measured_q=config.initial_q.copy(),
            clock=ClockMap(config.clock_uncertainty_ns),
            memory=ChunkMemory(config.memory_capacity), motion=initial_motion(config),
        )
        state.watermarks = Watermarks(config.watermarks)
        state.plausibility = Bounds.of(config.limits, config.control_period_ns,
                                       config.plausibility)
        return state

    # -- views ------------------------------------------------------------------------------

    @property
    def t_ms(self) -> int | float:
        return ns_to_ms(self.t)

    @property
    def card(self) -> PhaseCard:
        return self.config.phases.card(self.task.phase)

    @property
    def accepts_proposals(self) -> bool:
        return self.fallback.card.accepts_proposals and self.card.takes_proposals

    @property
    def controller_mode(self) -> str:
        return self.card.policy.controller_mode or self.config.client.controller_mode

    def hold_target(self) -> np.ndarray:
        """Where a hold that starts now holds: the measured state, inside the limits. Only
        a plausible sample is ever measured (:func:`kernel.core.authority.on_state`), so a
        hold never chases a glitched reading."""
        return self.config.limits.clip(self.measured_q)

    def context(self) -> AdmissionContext:
        client = self.config.client
        return AdmissionContext(
            t=self.t, session=self.session, allowlist=self.config.allowlist,
            skill=client.skill, skill_version=client.skill_version, phase=self.task.phase,
            controller_mode=self.controller_mode, calibration_epoch=client.calibration_epoch,
            action_dim=client.action_dim, action_units=client.action_units,
            action_frame=client.action_frame, queue_epoch=self.epoch,
            last_sequence=self.last_sequence, accepts_proposals=self.accepts_proposals,
            policy=self.card.policy, clock=self.clock, limits=self.config.limits,
            measured_q=self.measured_q,
        )

    # -- effects that are always logged -------------------------------------------------------

    def emit(self, line: Line) -> None:
        self.lines.append(line)

    def effect(self, effect: Effect) -> None:
        self.effects.append(effect)

    def decided(self, record: DecisionRecord) -> None:
        """Report a decision to the shell, typed (with the line that logs it)."""
        self.decisions.append(record)

    def next_job_id(self) -> int:
        self.jobs_issued += 1
        return self.jobs_issued

    def ask(self, job: ClearanceJob) -> int:
        """Ask the shell for a clearance check (a planned move's, a descent's); its id comes
        back with the result."""
        job = msgspec.structs.replace(job, job_id=self.next_job_id())
        self.effect(Compute(job=job))
        return job.job_id

    def purge(self, reason: ReasonCode | None = None) -> None:
        dropped = self.queue.purge()
        self.emit(QueueLine(t=self.t_ms, action=QueueAct.PURGE, queue_epoch=self.epoch,
                            dropped=dropped, reason=reason))
        self._queue_reset()

    def new_epoch(self, reason: ReasonCode | None = None) -> None:
        """A new queue epoch: everything older is purged and can never run again."""
        dropped = self.queue.purge()
        self.epoch += 1
        self.last_sequence = None
        self.observations.forget_answers()
        self.emit(QueueLine(t=self.t_ms, action=QueueAct.NEW_EPOCH, queue_epoch=self.epoch,
                            dropped=dropped, reason=reason))
        self._queue_reset()

    def _queue_reset(self) -> None:
        self.queue_version += 1
        self.executed_in_epoch = False
        self.underrun_since = None
        if self.watermarks is not None:
            self.watermarks.answered()

    def fire(self, trigger: ReasonCode, immediate: bool = False,
             detail: str | None = None) -> bool:
        """Raise a fallback trigger; apply and log the transition if one happens."""
        transition = self.fallback.fire(trigger, immediate)
        if transition is None:
            return False
        self.apply(transition, detail=detail)
        return True

    def apply(self, transition: Transition, queue: QueueAction | None = None,
              detail: str | None = None) -> None:
        """Log a fallback transition and carry out its queue action and task mirroring."""
        card = MODES[transition.target]
        action = queue if queue is not None else card.queue
        self.emit(TransitionLine(
            t=self.t_ms, machine=Machine.FALLBACK, from_=transition.source, to=transition.target,
            trigger=transition.trigger, owner=card.owner, command=card.command,
            queue=action, recovery=card.recovery, detail=detail,
        ))
        if action is QueueAction.NEW_EPOCH:
            self.new_epoch(transition.trigger)
        elif action is QueueAction.PURGE:
            self.purge(transition.trigger)
        self.hold_q = None
        if transition.target is Mode.DEGRADED:
            self.session = None  # DEGRADED returns only through a new handshake
            self.effect(EndSession(reason=transition.trigger))
        mirrored = {Mode.SAFE_HOLD: TaskPhase.SAFE_HOLD, Mode.HUMAN_RECOVERY:
                    TaskPhase.HUMAN_RECOVERY}.get(transition.target)
        if mirrored is not None:
            self.log_task(self.task.suspend(mirrored, transition.trigger))

    def log_task(self, decision: TaskDecision | None, requested: str | None = None) -> None:
        if decision is None:
            return
        if decision.accepted:
            self.emit(TransitionLine(t=self.t_ms, machine=Machine.TASK, from_=decision.source,
                                     to=decision.target, trigger=decision.trigger))
            if TaskPhase.CONTACT in (decision.source, decision.target):
                drop_descent(self.motion, self.t, self.emit,
                             f"superseded: the task went from {decision.source} to "
                             f"{decision.target}")
            if decision.target is TaskPhase.CONTACT:
                self.motion.contact.reset()  # a new contact starts from a compliant hold
            return
        self.emit(TransitionLine(
            t=self.t_ms, machine=Machine.TASK, from_=decision.source, to=decision.source,
            trigger=decision.trigger, accepted=False, requested=requested or decision.target,
            reasons=decision.reasons, missing_evidence=decision.missing_evidence,
        ))

    def refuse(self, machine: Machine, requested: str, trigger: ReasonCode,
               detail: str) -> None:
        """Log a request the machine did not grant (the state stays where it is)."""
        current = self.fallback.mode if machine is Machine.FALLBACK else self.task.phase
        self.emit(TransitionLine(
            t=self.t_ms, machine=machine, from_=current, to=current, trigger=trigger,
            accepted=False, requested=requested, reasons=(trigger,), detail=detail,
        ))
