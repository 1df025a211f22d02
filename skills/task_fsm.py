"""The task FSM (docs/contract.md §6): phases advance on evidence, never on confidence.

``IDLE → VALIDATE → FREE_SPACE → PRE_CONTACT → CONTACT → VERIFY → RETREAT`` with
``SAFE_HOLD ↔ HUMAN_RECOVERY → ABORT``. A guarded transition needs every piece of its evidence,
given as booleans that are exactly ``true``. A request by the policy (or any learned score) may
lead to SAFE_HOLD and nowhere else: it can never authorize a guarded transition.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum

from assurance.reasons import ReasonCode
from skills.phases import SUSPENDED, WORK_PHASES, TaskPhase

P = TaskPhase


class Requester(StrEnum):
    FSM = "fsm"
    POLICY = "policy"
    OPERATOR = "operator"


CONTACT_EVIDENCE = (
    "pose_within_tolerance", "controller_mode_ack", "force_fresh", "contact_envelope_valid",
)

GUARDS: dict[tuple[TaskPhase, TaskPhase], tuple[str, ...]] = {
    (P.PRE_CONTACT, P.CONTACT): CONTACT_EVIDENCE,
    (P.VALIDATE, P.CONTACT): CONTACT_EVIDENCE,  # no way into contact without the evidence
}

EDGES: dict[TaskPhase, frozenset[TaskPhase]] = {
    P.IDLE: frozenset({P.VALIDATE}),
    P.VALIDATE: frozenset({P.IDLE, *WORK_PHASES}),
    P.FREE_SPACE: frozenset({P.PRE_CONTACT, P.RETREAT}),
    P.PRE_CONTACT: frozenset({P.CONTACT, P.FREE_SPACE, P.RETREAT}),
    P.CONTACT: frozenset({P.VERIFY, P.RETREAT}),
    P.VERIFY: frozenset({P.RETREAT, P.PRE_CONTACT}),
    P.RETREAT: frozenset({P.IDLE, P.FREE_SPACE}),
    P.SAFE_HOLD: frozenset({P.HUMAN_RECOVERY, P.ABORT, P.VALIDATE}),
    P.HUMAN_RECOVERY: frozenset({P.SAFE_HOLD, P.ABORT, P.VALIDATE}),
    P.ABORT: frozenset({P.IDLE}),
}


@dataclass(frozen=True, slots=True)
class TaskDecision:
    accepted: bool
    source: TaskPhase
    target: TaskPhase
    trigger: ReasonCode
    reasons: tuple[ReasonCode, ...] = ()
    missing_evidence: tuple[str, ...] = ()


class TaskMachine:
    def __init__(
        self, phase: TaskPhase,
        guards: Mapping[tuple[TaskPhase, TaskPhase], tuple[str, ...]] = GUARDS,
    ) -> None:
        self.phase = phase
        self.resume_phase: TaskPhase | None = None
        self.guards = dict(guards)

    def request(
        self, target: TaskPhase, evidence: Mapping[str, object], by: Requester,
        fsm_has_authority: bool = True,
    ) -> TaskDecision:
        """Decide a requested transition; the phase changes only if it is accepted.

        Anyone may ask for SAFE_HOLD from a phase that is not already suspended; only the
        operator acts on a suspended task (a takeover ends by the operator's release, an
        aborted task stays aborted).
        """
        if target is P.SAFE_HOLD and self.phase not in SUSPENDED and self.phase is not P.ABORT:
            return self._move(P.SAFE_HOLD, ReasonCode.HOLD_REQUESTED)
        reasons: list[ReasonCode] = []
        missing = self._missing(target, evidence)
        legal = target in EDGES[self.phase]
        fsm_outranked = not fsm_has_authority and target not in SUSPENDED
        human_owns = self.phase is P.HUMAN_RECOVERY and by is not Requester.OPERATOR
        if by is Requester.POLICY or fsm_outranked or human_owns:
            reasons.append(ReasonCode.NO_AUTHORITY)
        if missing or not legal:
            reasons.append(ReasonCode.GUARD_FAILED)
        if reasons:
            return TaskDecision(False, self.phase, target, reasons[0], tuple(reasons), missing)
        return self._move(target, ReasonCode.GUARD_PASSED)

    def suspend(self, target: TaskPhase, trigger: ReasonCode) -> TaskDecision | None:
        """The fallback machine took authority: mirror SAFE_HOLD / HUMAN_RECOVERY.

        An aborted task is not mirrored: it has nothing to suspend, and leaves ABORT only for
        IDLE (the fallback machine still holds the arm)."""
        if self.phase is target or self.phase is P.ABORT:
            return None
        return self._move(target, trigger)

    def begin_validation(self, trigger: ReasonCode) -> TaskDecision | None:
        """Enter VALIDATE on the way back to work (after recovery or a new handshake).

        An aborted task stays aborted: it leaves ABORT only for IDLE, and validates from there
        like any new task.
        """
        if self.phase in (P.VALIDATE, P.ABORT):
            return None
        if self.phase in WORK_PHASES:
            self.resume_phase = self.phase
        return self._move(P.VALIDATE, trigger)

    def finish_validation(self) -> TaskDecision | None:
        """VALIDATE passed: return to the phase that was suspended, if there is one.

        A task suspended in CONTACT resumes in PRE_CONTACT: the contact evidence it entered
        with is stale after a hold, so contact is entered again only through its guard.
        """
        if self.phase is not P.VALIDATE or self.resume_phase is None:
            return None
        target, self.resume_phase = self.resume_phase, None
        if target is P.CONTACT:
            target = P.PRE_CONTACT
        return self._move(target, ReasonCode.GUARD_PASSED)

    def _missing(self, target: TaskPhase, evidence: Mapping[str, object]) -> tuple[str, ...]:
        required = self.guards.get((self.phase, target), ())
        return tuple(key for key in required if evidence.get(key) is not True)

    def _move(self, target: TaskPhase, trigger: ReasonCode) -> TaskDecision:
        source = self.phase
        if source in WORK_PHASES and target in SUSPENDED:
            self.resume_phase = source
        elif target in (P.ABORT, P.IDLE):
            self.resume_phase = None  # the suspended work is given up, never resumed later
        self.phase = target
        return TaskDecision(True, source, target, trigger)
