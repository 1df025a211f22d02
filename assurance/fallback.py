"""The fallback state machine (docs/contract.md §6), as a table.

Every transition names its trigger (a reason code), the states it may leave, its debounce,
the owner of motion afterwards, what happens to the queue, the command the controller gets, and
the precondition for recovery. E_STOP is reachable from every state; DEGRADED returns to RUNNING
only through a new handshake and VALIDATE; the operator's ``accept_recovery`` is the only way
back from the hold-type states. A trigger that does not apply to the current state changes
nothing: a less severe trigger never pulls the machine out of a more severe state.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from assurance.reasons import ReasonCode as R


class Mode(StrEnum):
    RUNNING = "RUNNING"
    DEGRADED = "DEGRADED"
    SAFE_HOLD = "SAFE_HOLD"
    REPLAN_OR_RETREAT = "REPLAN_OR_RETREAT"
    CONTACT_FALLBACK = "CONTACT_FALLBACK"
    CONTROLLER_STOP = "CONTROLLER_STOP"
    HUMAN_RECOVERY = "HUMAN_RECOVERY"
    E_STOP = "E_STOP"


class Owner(StrEnum):
    POLICY = "policy"
    CONTACT = "contact"
    PLANNER = "planner"
    FALLBACK = "fallback"
    HUMAN = "human"
    SAFETY = "safety"


class FallbackCommand(StrEnum):
    SETPOINT = "setpoint"
    HOLD = "hold"
    CONTACT = "contact"
    RETREAT = "retreat"
    STOP = "stop"


class QueueAction(StrEnum):
    KEEP = "keep"
    PURGE = "purge"
    NEW_EPOCH = "new_epoch"


@dataclass(frozen=True, slots=True)
class ModeCard:
    """What a fallback state means for motion, and how to leave it."""

    owner: Owner
    command: FallbackCommand
    queue: QueueAction
    accepts_proposals: bool
    recovery: str


MODES: dict[Mode, ModeCard] = {
    Mode.RUNNING: ModeCard(Owner.POLICY, FallbackCommand.SETPOINT, QueueAction.KEEP, True, "-"),
    Mode.DEGRADED: ModeCard(
        Owner.FALLBACK, FallbackCommand.HOLD, QueueAction.NEW_EPOCH, False,
        "new handshake ACCEPT, then VALIDATE passes"),
    Mode.SAFE_HOLD: ModeCard(
        Owner.FALLBACK, FallbackCommand.HOLD, QueueAction.PURGE, False, "operator accept_recovery"),
    Mode.REPLAN_OR_RETREAT: ModeCard(
        Owner.PLANNER, FallbackCommand.RETREAT, QueueAction.PURGE, False,
        "operator accept_recovery"),
    Mode.CONTACT_FALLBACK: ModeCard(
        Owner.CONTACT, FallbackCommand.RETREAT, QueueAction.PURGE, False,
        "operator accept_recovery"),
    Mode.CONTROLLER_STOP: ModeCard(
        Owner.SAFETY, FallbackCommand.STOP, QueueAction.PURGE, False,
        "controller reports ok, then operator accept_recovery"),
    Mode.HUMAN_RECOVERY: ModeCard(
        Owner.HUMAN, FallbackCommand.HOLD, QueueAction.PURGE, False,
        "operator release (to SAFE_HOLD) or accept_recovery"),
    Mode.E_STOP: ModeCard(
        Owner.SAFETY, FallbackCommand.STOP, QueueAction.PURGE, False,
        "e-stop cleared, then operator reset (to SAFE_HOLD)"),
}

_ALL = frozenset(Mode)
_SOFT = frozenset({Mode.RUNNING, Mode.DEGRADED, Mode.REPLAN_OR_RETREAT})
_NOT_ESTOP = _ALL - {Mode.E_STOP}
_CONTACT_SOURCES = _SOFT | {Mode.SAFE_HOLD}
_RECOVERABLE = frozenset({
    Mode.SAFE_HOLD, Mode.REPLAN_OR_RETREAT, Mode.CONTACT_FALLBACK, Mode.HUMAN_RECOVERY,
    Mode.CONTROLLER_STOP,
})


@dataclass(frozen=True, slots=True)
class Rule:
    trigger: R
    to: Mode
    sources: frozenset[Mode]
    debounce: int = 1
    """Consecutive occurrences needed before the transition fires."""
    group: str = ""
    """Triggers of one group share their debounce counter (e.g. every timing refusal)."""

    @property
    def counter(self) -> str:
        return self.group or self.trigger


def _rules(degrade_after: int) -> dict[R, Rule]:
    timing = (R.OBSERVATION_STALE, R.EXPIRED, R.REORDERED, R.TRIM_FORBIDDEN, R.CLOCK_INVALID,
              R.UNKNOWN_OBSERVATION, R.MALFORMED, R.NONFINITE, R.RTC_DELAY_EXCEEDED,
              R.RTC_PREFIX_MISMATCH)
    compat = (R.CHECKPOINT_NOT_ALLOWED, R.CONFIG_MISMATCH, R.SCHEMA_MISMATCH,
              R.CONTROLLER_MODE_MISMATCH, R.CALIBRATION_MISMATCH, R.PROTOCOL_MISMATCH,
              R.ID_CONFLICT, R.OLD_QUEUE_EPOCH, R.FUTURE_QUEUE_EPOCH, R.SKILL_MISMATCH)
    rules = [
        Rule(R.E_STOP, Mode.E_STOP, _ALL - {Mode.E_STOP}),
        Rule(R.WATCHDOG, Mode.CONTROLLER_STOP, _NOT_ESTOP - {Mode.CONTROLLER_STOP}),
        Rule(R.CONTROLLER_FAULT, Mode.CONTROLLER_STOP, _NOT_ESTOP - {Mode.CONTROLLER_STOP}),
        Rule(R.CONTROLLER_REJECT, Mode.CONTROLLER_STOP, _NOT_ESTOP - {Mode.CONTROLLER_STOP}),
        Rule(R.ENVELOPE, Mode.CONTROLLER_STOP, _NOT_ESTOP - {Mode.CONTROLLER_STOP}),
        Rule(R.RECORDER_FAILED, Mode.CONTROLLER_STOP, _NOT_ESTOP - {Mode.CONTROLLER_STOP}),
        Rule(R.HUMAN_TAKEOVER, Mode.HUMAN_RECOVERY, _NOT_ESTOP - {Mode.HUMAN_RECOVERY}),
        Rule(R.CONTACT_ANOMALY, Mode.CONTACT_FALLBACK, _CONTACT_SOURCES),
        Rule(R.STATE_DIVERGED, Mode.SAFE_HOLD, _SOFT),
        Rule(R.STATE_IMPLAUSIBLE, Mode.SAFE_HOLD, _SOFT),
        Rule(R.COLLISION, Mode.SAFE_HOLD, _SOFT),
        Rule(R.OOD, Mode.SAFE_HOLD, _SOFT),
        Rule(R.HOLD_REQUESTED, Mode.SAFE_HOLD, _SOFT),
        Rule(R.UNDERRUN, Mode.SAFE_HOLD, _SOFT),
        Rule(R.CAMERA_LOST, Mode.SAFE_HOLD, _SOFT),
        Rule(R.INFEASIBLE, Mode.REPLAN_OR_RETREAT, frozenset({Mode.RUNNING})),
        Rule(R.LINK_LOST, Mode.DEGRADED, frozenset({Mode.RUNNING})),
        Rule(R.HANDSHAKE_REQUIRED, Mode.DEGRADED, frozenset({Mode.RUNNING})),
        *(Rule(code, Mode.DEGRADED, frozenset({Mode.RUNNING}), degrade_after, "timing")
          for code in timing),
        *(Rule(code, Mode.DEGRADED, frozenset({Mode.RUNNING})) for code in compat),
    ]
    return {rule.trigger: rule for rule in rules}


# Chunk-refusal reasons that lead somewhere, most severe first: a refusal that carries several
# fires only the first that applies.
REFUSAL_PRIORITY: tuple[R, ...] = (
    R.STATE_DIVERGED, R.COLLISION, R.INFEASIBLE, R.CHECKPOINT_NOT_ALLOWED, R.CONFIG_MISMATCH,
    R.SCHEMA_MISMATCH, R.CONTROLLER_MODE_MISMATCH, R.CALIBRATION_MISMATCH, R.ID_CONFLICT,
    R.OBSERVATION_STALE, R.EXPIRED, R.TRIM_FORBIDDEN, R.RTC_DELAY_EXCEEDED, R.RTC_PREFIX_MISMATCH,
    R.REORDERED, R.CLOCK_INVALID, R.UNKNOWN_OBSERVATION, R.NONFINITE, R.MALFORMED,
)

# A refusal carrying one of these is about a chunk that does not belong to the present context
# (another phase, an old epoch, no session, no authority): refusing it is the whole answer, it
# says nothing about the health of the current motion.
# A second answer to an observation is one of them: the queue runs on the admitted answer.
IRRELEVANT: frozenset[R] = frozenset({
    R.DUPLICATE, R.OLD_QUEUE_EPOCH, R.FUTURE_QUEUE_EPOCH, R.PHASE_MISMATCH,
    R.HANDSHAKE_REQUIRED, R.NO_AUTHORITY, R.SKILL_MISMATCH, R.OBSERVATION_ANSWERED,
})


@dataclass(frozen=True, slots=True)
class Transition:
    source: Mode
    target: Mode
    trigger: R


class FallbackMachine:
    def __init__(self, degrade_after: int = 3, mode: Mode = Mode.RUNNING) -> None:
        if degrade_after < 1:
            raise ValueError("degrade_after must be at least 1")
        self.rules = _rules(degrade_after)
        self.mode = mode
        self.cause: R | None = None
        self._counts: dict[str, int] = {}

    @property
    def card(self) -> ModeCard:
        return MODES[self.mode]

    def fire(self, trigger: R, immediate: bool = False) -> Transition | None:
        """Count ``trigger``; transition when its rule applies and its debounce is reached
        (at once when ``immediate``: the event is conclusive on its own, e.g. a rejected
        handshake whose first reason happens to be a debounced one)."""
        rule = self.rules.get(trigger)
        if rule is None or self.mode not in rule.sources:
            return None
        count = self._counts.get(rule.counter, 0) + 1
        if count < rule.debounce and not immediate:
            self._counts[rule.counter] = count
            return None
        return self._go(rule.to, trigger)

    def clear_debounce(self) -> None:
        """A healthy chunk was admitted: consecutive-refusal counters start again."""
        self._counts.clear()

    def recover(self, handshake_valid: bool, controller_ok: bool) -> Transition | str:
        """Operator ``accept_recovery``: a transition, or why the precondition is not met."""
        if self.mode not in _RECOVERABLE:
            return f"nothing to recover from in {self.mode}"
        if self.mode is Mode.CONTROLLER_STOP and not controller_ok:
            return "controller has not reported ok"
        target = Mode.RUNNING if handshake_valid else Mode.DEGRADED
        return self._go(target, R.RECOVERY_ACCEPTED)

    def release(self) -> Transition | str:
        if self.mode is not Mode.HUMAN_RECOVERY:
            return f"no takeover to release in {self.mode}"
        return self._go(Mode.SAFE_HOLD, R.OPERATOR_RELEASE)

    def reset(self, estop_clear: bool) -> Transition | str:
        if self.mode is not Mode.E_STOP:
            return f"no e-stop to reset in {self.mode}"
        if not estop_clear:
            return "e-stop is still asserted by the controller"
        return self._go(Mode.SAFE_HOLD, R.OPERATOR_RESET)

    def validated(self) -> Transition | None:
        """VALIDATE passed after a new handshake: DEGRADED returns to RUNNING."""
        if self.mode is not Mode.DEGRADED:
            return None
        return self._go(Mode.RUNNING, R.RECOVERY_ACCEPTED)

    def _go(self, target: Mode, trigger: R) -> Transition:
        transition = Transition(self.mode, target, trigger)
        self.mode, self.cause = target, (trigger if target is not Mode.RUNNING else None)
        self._counts.clear()
        return transition


def refusal_trigger(reasons: tuple[R, ...]) -> R | None:
    """The fallback trigger a refused chunk raises, or None if it raises none."""
    if any(code in IRRELEVANT for code in reasons):
        return None
    present = set(reasons)
    return next((code for code in REFUSAL_PRIORITY if code in present), None)
