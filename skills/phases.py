"""Task phases and their contract cards: who proposes, who executes, how fresh.

The card is data. The runtime reads it to decide whether a phase takes learned proposals and
who owns motion when no proposal is running; the gates read its :class:`PhasePolicy`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum

from assurance.policy import PhasePolicy


class TaskPhase(StrEnum):
    IDLE = "IDLE"
    VALIDATE = "VALIDATE"
    FREE_SPACE = "FREE_SPACE"
    PRE_CONTACT = "PRE_CONTACT"
    CONTACT = "CONTACT"
    VERIFY = "VERIFY"
    RETREAT = "RETREAT"
    SAFE_HOLD = "SAFE_HOLD"
    HUMAN_RECOVERY = "HUMAN_RECOVERY"
    ABORT = "ABORT"


WORK_PHASES = frozenset({
    TaskPhase.FREE_SPACE, TaskPhase.PRE_CONTACT, TaskPhase.CONTACT, TaskPhase.VERIFY,
    TaskPhase.RETREAT,
})
SUSPENDED = frozenset({TaskPhase.SAFE_HOLD, TaskPhase.HUMAN_RECOVERY, TaskPhase.ABORT})


class Executor(StrEnum):
    """Who executes motion in a phase while the fallback machine is RUNNING."""

    POLICY = "policy"
    """Admitted chunk actions go out as setpoints; an empty queue is an underrun hold."""
    CONTACT = "contact"
    """The impedance law owns motion; admitted chunks are only bounded targets for it."""
    PLANNER = "planner"
    """A classical trajectory (transport, retreat); learned proposals are refused."""
    HOLD = "hold"
    """Nothing moves (idle, validation, independent evaluation)."""


@dataclass(frozen=True, slots=True)
class PhaseCard:
    phase: TaskPhase
    executor: Executor
    policy: PhasePolicy = field(default_factory=PhasePolicy)
    proposal_owner: str = ""
    approval_owner: str = ""
    fallback: str = ""
    proposals: bool | None = None
    """Whether learned chunks are admitted in this phase; None: the executor decides."""

    @property
    def takes_proposals(self) -> bool:
        if self.proposals is not None:
            return self.proposals
        return self.executor in (Executor.POLICY, Executor.CONTACT)


DEFAULT_EXECUTORS: dict[TaskPhase, Executor] = {
    TaskPhase.IDLE: Executor.HOLD,
    TaskPhase.VALIDATE: Executor.HOLD,
    TaskPhase.FREE_SPACE: Executor.POLICY,
    TaskPhase.PRE_CONTACT: Executor.POLICY,
    TaskPhase.CONTACT: Executor.CONTACT,
    TaskPhase.VERIFY: Executor.HOLD,
    TaskPhase.RETREAT: Executor.PLANNER,
    TaskPhase.SAFE_HOLD: Executor.HOLD,
    TaskPhase.HUMAN_RECOVERY: Executor.HOLD,
    TaskPhase.ABORT: Executor.HOLD,
}

_DESCRIPTIONS: dict[TaskPhase, tuple[str, str, str]] = {
    TaskPhase.FREE_SPACE: ("planner or learned pose", "IK/collision/rate gate", "replan or hold"),
    TaskPhase.PRE_CONTACT: ("learned chunk", "workspace/rate/phase gate", "staging retreat"),
    TaskPhase.CONTACT: ("bounded target only", "force/contact guard", "contact fallback"),
    TaskPhase.VERIFY: ("independent evaluator", "task FSM", "retry or inspect"),
    TaskPhase.RETREAT: ("classical trajectory", "collision/safety", "stop or human recovery"),
}


class PhaseBook:
    """The cards of every phase: configured ones, and defaults for the rest."""

    def __init__(self, cards: Mapping[TaskPhase, PhaseCard] | None = None) -> None:
        self._cards = dict(cards or {})

    def card(self, phase: TaskPhase) -> PhaseCard:
        found = self._cards.get(phase)
        if found is not None:
            return found
        proposal, approval, fallback = _DESCRIPTIONS.get(phase, ("", "", ""))
        return PhaseCard(phase, DEFAULT_EXECUTORS[phase], PhasePolicy(), proposal, approval,
                         fallback)

    @staticmethod
    def make_card(
        phase: TaskPhase, policy: PhasePolicy, executor: Executor | None = None,
        proposals: bool | None = None,
    ) -> PhaseCard:
        proposal, approval, fallback = _DESCRIPTIONS.get(phase, ("", "", ""))
        return PhaseCard(phase, executor or DEFAULT_EXECUTORS[phase], policy, proposal,
                         approval, fallback, proposals)
