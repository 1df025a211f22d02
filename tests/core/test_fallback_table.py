"""Every rule of the fallback FSM, checked against a table written here from the contract.

``EXPECTED`` restates docs/contract.md §6 and §8 ("Fallback and task machines"): for each
trigger, the state it leads to, the states it may leave, and how many consecutive occurrences
it needs. The machine is judged only by what it does when fired (never by reading its own
table): every trigger from every state it applies to, and from every state it must not change;
debounce, the shared timing counter, ``clear_debounce``, ``immediate``; recover, release, reset
and validated with their preconditions; E_STOP from every state; and totality: every reason
code is a trigger here or explicitly not one.
"""

from __future__ import annotations

from dataclasses import dataclass

import pytest
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from assurance.fallback import (
    IRRELEVANT,
    MODES,
    REFUSAL_PRIORITY,
    FallbackCommand,
    FallbackMachine,
    Mode,
    Owner,
    QueueAction,
    Transition,
)
from assurance.reasons import ReasonCode as R

DEGRADE_AFTER = 3
ALL = frozenset(Mode)
RUNNING = frozenset({Mode.RUNNING})
SOFT = frozenset({Mode.RUNNING, Mode.DEGRADED, Mode.REPLAN_OR_RETREAT})
TIMING = (R.OBSERVATION_STALE, R.EXPIRED, R.REORDERED, R.TRIM_FORBIDDEN, R.CLOCK_INVALID,
          R.UNKNOWN_OBSERVATION, R.MALFORMED, R.NONFINITE, R.RTC_PREFIX_MISMATCH,
          R.RTC_DELAY_EXCEEDED)
"""Timing refusals: one shared counter, DEGRADED after ``degrade_after`` in a row."""
AT_ONCE_TO_DEGRADED = (
    R.LINK_LOST, R.HANDSHAKE_REQUIRED, R.CHECKPOINT_NOT_ALLOWED, R.CONFIG_MISMATCH,
    R.SCHEMA_MISMATCH, R.CONTROLLER_MODE_MISMATCH, R.CALIBRATION_MISMATCH, R.PROTOCOL_MISMATCH,
    R.ID_CONFLICT, R.OLD_QUEUE_EPOCH, R.FUTURE_QUEUE_EPOCH, R.SKILL_MISMATCH,
)
"""Link loss, and every reason a rejected handshake or a compatibility refusal can carry."""


@dataclass(frozen=True)
class Expected:
    to: Mode
    sources: frozenset[Mode]
    debounce: int = 1


EXPECTED: dict[R, Expected] = {
    R.E_STOP: Expected(Mode.E_STOP, ALL - {Mode.E_STOP}),
    **{code: Expected(Mode.CONTROLLER_STOP, ALL - {Mode.E_STOP, Mode.CONTROLLER_STOP})
       for code in (R.WATCHDOG, R.CONTROLLER_FAULT, R.CONTROLLER_REJECT, R.ENVELOPE,
                    R.RECORDER_FAILED)},
    R.HUMAN_TAKEOVER: Expected(Mode.HUMAN_RECOVERY, ALL - {Mode.E_STOP, Mode.HUMAN_RECOVERY}),
    R.CONTACT_ANOMALY: Expected(Mode.CONTACT_FALLBACK, SOFT | {Mode.SAFE_HOLD}),
    **{code: Expected(Mode.SAFE_HOLD, SOFT)
       for code in (R.STATE_DIVERGED, R.STATE_IMPLAUSIBLE, R.OOD, R.HOLD_REQUESTED,
                    R.UNDERRUN, R.COLLISION, R.CAMERA_LOST)},
    R.INFEASIBLE: Expected(Mode.REPLAN_OR_RETREAT, RUNNING),
    **{code: Expected(Mode.DEGRADED, RUNNING) for code in AT_ONCE_TO_DEGRADED},
    **{code: Expected(Mode.DEGRADED, RUNNING, DEGRADE_AFTER) for code in TIMING},
}

NOT_TRIGGERS: frozenset[R] = frozenset({
    R.DUPLICATE,  # ignored: decided when it first arrived
    R.PHASE_MISMATCH, R.NO_AUTHORITY,  # made for another context: the refusal is the answer
    R.RECOVERY_ACCEPTED, R.OPERATOR_RELEASE, R.OPERATOR_RESET,  # outcomes of operator requests
    R.GUARD_FAILED, R.GUARD_PASSED, R.HANDSHAKE_ACCEPTED,  # task FSM and handshake outcomes
    R.PHASE_OWNER,  # a tick's reason, not an event
    R.OBSERVATION_ANSWERED,  # an unsolicited answer: refused before any gate, says nothing
})

RECOVERABLE = frozenset({Mode.SAFE_HOLD, Mode.REPLAN_OR_RETREAT, Mode.CONTACT_FALLBACK,
                         Mode.HUMAN_RECOVERY, Mode.CONTROLLER_STOP})


def machine(mode: Mode = Mode.RUNNING) -> FallbackMachine:
    return FallbackMachine(degrade_after=DEGRADE_AFTER, mode=mode)


def pairs(applies: bool) -> list[tuple[R, Mode]]:
    return [(code, mode) for code, rule in EXPECTED.items() for mode in Mode
            if (mode in rule.sources) == applies]


# --- totality ----------------------------------------------------------------------------------


def test_every_reason_code_is_a_trigger_or_explicitly_not_one() -> None:
    assert not set(EXPECTED) & NOT_TRIGGERS
    assert set(EXPECTED) | NOT_TRIGGERS == set(R)


@pytest.mark.parametrize("code", sorted(NOT_TRIGGERS))
@pytest.mark.parametrize("mode", list(Mode))
def test_a_code_that_is_not_a_trigger_changes_nothing(code: R, mode: Mode) -> None:
    fsm = machine(mode)
    for _ in range(DEGRADE_AFTER + 1):
        assert fsm.fire(code) is None and fsm.fire(code, immediate=True) is None
    assert fsm.mode is mode


def test_the_refusal_tables_are_consistent_with_the_rules() -> None:
    assert not set(REFUSAL_PRIORITY) & IRRELEVANT
    for code in REFUSAL_PRIORITY:
        assert Mode.RUNNING in EXPECTED[code].sources
    assert set(IRRELEVANT) <= set(EXPECTED) | NOT_TRIGGERS


# --- each rule, from each state ----------------------------------------------------------------


@pytest.mark.parametrize(("code", "mode"), pairs(applies=True))
def test_a_trigger_moves_every_state_it_applies_to(code: R, mode: Mode) -> None:
    rule, fsm = EXPECTED[code], machine(mode)
    for _ in range(rule.debounce - 1):
        assert fsm.fire(code) is None and fsm.mode is mode
    assert fsm.fire(code) == Transition(mode, rule.to, code)
    assert fsm.mode is rule.to and fsm.cause is code


@pytest.mark.parametrize(("code", "mode"), pairs(applies=False))
def test_a_trigger_leaves_every_other_state_alone(code: R, mode: Mode) -> None:
    fsm = machine(mode)
    cause = fsm.cause
    for _ in range(EXPECTED[code].debounce + 1):
        assert fsm.fire(code) is None
    assert fsm.fire(code, immediate=True) is None
    assert fsm.mode is mode and fsm.cause is cause


@pytest.mark.parametrize("mode", list(Mode))
def test_e_stop_is_reachable_from_every_state_but_itself(mode: Mode) -> None:
    fsm = machine(mode)
    transition = fsm.fire(R.E_STOP)
    assert fsm.mode is Mode.E_STOP
    assert (transition is None) == (mode is Mode.E_STOP)


def test_link_lost_degrades_a_running_machine_at_once() -> None:
    fsm = machine()
    assert fsm.fire(R.LINK_LOST) == Transition(Mode.RUNNING, Mode.DEGRADED, R.LINK_LOST)
    assert fsm.card.queue is QueueAction.NEW_EPOCH and not fsm.card.accepts_proposals


# --- debounce ----------------------------------------------------------------------------------


@pytest.mark.parametrize("last", TIMING)
def test_timing_refusals_share_one_counter(last: R) -> None:
    fsm = machine()
    others = [code for code in TIMING if code is not last]
    for code in others[:DEGRADE_AFTER - 1]:
        assert fsm.fire(code) is None
    assert fsm.fire(last) == Transition(Mode.RUNNING, Mode.DEGRADED, last)


def test_clear_debounce_restarts_the_count() -> None:
    fsm = machine()
    for _ in range(DEGRADE_AFTER - 1):
        assert fsm.fire(R.EXPIRED) is None
    fsm.clear_debounce()
    for _ in range(DEGRADE_AFTER - 1):
        assert fsm.fire(R.REORDERED) is None
    assert fsm.mode is Mode.RUNNING
    assert fsm.fire(R.NONFINITE) is not None


def test_any_transition_restarts_the_count() -> None:
    fsm = machine()
    for _ in range(DEGRADE_AFTER - 1):
        fsm.fire(R.EXPIRED)
    fsm.fire(R.HOLD_REQUESTED)
    fsm.recover(handshake_valid=True, controller_ok=True)
    assert fsm.mode is Mode.RUNNING
    assert fsm.fire(R.EXPIRED) is None


def test_a_timing_refusal_outside_running_does_not_count() -> None:
    fsm = machine(Mode.DEGRADED)
    for _ in range(DEGRADE_AFTER + 1):
        assert fsm.fire(R.EXPIRED) is None
    assert fsm.validated() is not None
    for _ in range(DEGRADE_AFTER - 1):
        assert fsm.fire(R.EXPIRED) is None
    assert fsm.mode is Mode.RUNNING


def test_a_non_timing_trigger_that_does_not_apply_leaves_the_count_alone() -> None:
    fsm = machine()
    for _ in range(DEGRADE_AFTER - 1):
        fsm.fire(R.EXPIRED)
    assert fsm.fire(R.PHASE_MISMATCH) is None and isinstance(fsm.release(), str)
    assert fsm.fire(R.EXPIRED) is not None


@pytest.mark.parametrize("code", TIMING)
def test_immediate_skips_the_debounce_only_where_the_rule_applies(code: R) -> None:
    assert machine().fire(code, immediate=True) == Transition(Mode.RUNNING, Mode.DEGRADED, code)
    assert machine(Mode.SAFE_HOLD).fire(code, immediate=True) is None


@pytest.mark.parametrize("degrade_after", [1, 2, 5])
def test_degrade_after_is_the_number_of_timing_refusals_in_a_row(degrade_after: int) -> None:
    fsm = FallbackMachine(degrade_after=degrade_after)
    for _ in range(degrade_after - 1):
        assert fsm.fire(R.OBSERVATION_STALE) is None
    assert fsm.fire(R.OBSERVATION_STALE) is not None


@pytest.mark.parametrize("degrade_after", [0, -1])
def test_degrade_after_below_one_is_refused(degrade_after: int) -> None:
    with pytest.raises(ValueError, match="degrade_after"):
        FallbackMachine(degrade_after=degrade_after)


# --- operator requests and validation ----------------------------------------------------------


@pytest.mark.parametrize("mode", list(Mode))
@pytest.mark.parametrize("handshake_valid", [True, False])
@pytest.mark.parametrize("controller_ok", [True, False])
def test_recover(mode: Mode, handshake_valid: bool, controller_ok: bool) -> None:
    fsm = machine(mode)
    result = fsm.recover(handshake_valid=handshake_valid, controller_ok=controller_ok)
    allowed = mode in RECOVERABLE and (mode is not Mode.CONTROLLER_STOP or controller_ok)
    if not allowed:
        assert isinstance(result, str) and result and fsm.mode is mode
        return
    target = Mode.RUNNING if handshake_valid else Mode.DEGRADED
    assert result == Transition(mode, target, R.RECOVERY_ACCEPTED)
    assert fsm.mode is target
    assert fsm.cause is (None if target is Mode.RUNNING else R.RECOVERY_ACCEPTED)


@pytest.mark.parametrize("mode", list(Mode))
def test_release_ends_only_a_takeover_toward_safe_hold(mode: Mode) -> None:
    fsm = machine(mode)
    result = fsm.release()
    if mode is Mode.HUMAN_RECOVERY:
        assert result == Transition(mode, Mode.SAFE_HOLD, R.OPERATOR_RELEASE)
    else:
        assert isinstance(result, str) and result and fsm.mode is mode


@pytest.mark.parametrize("mode", list(Mode))
@pytest.mark.parametrize("estop_clear", [True, False])
def test_reset_leaves_only_a_cleared_e_stop_toward_safe_hold(mode: Mode, estop_clear: bool) -> None:
    fsm = machine(mode)
    result = fsm.reset(estop_clear=estop_clear)
    if mode is Mode.E_STOP and estop_clear:
        assert result == Transition(mode, Mode.SAFE_HOLD, R.OPERATOR_RESET)
    else:
        assert isinstance(result, str) and result and fsm.mode is mode


@pytest.mark.parametrize("mode", list(Mode))
def test_validated_returns_only_degraded_to_running(mode: Mode) -> None:
    fsm = machine(mode)
    result = fsm.validated()
    if mode is Mode.DEGRADED:
        assert result == Transition(mode, Mode.RUNNING, R.RECOVERY_ACCEPTED)
        assert fsm.cause is None
    else:
        assert result is None and fsm.mode is mode


# --- what each state means for motion (docs/contract.md §8, "Who owns each tick") ---------------


CARDS = {
    Mode.RUNNING: (Owner.POLICY, FallbackCommand.SETPOINT, QueueAction.KEEP, True),
    Mode.DEGRADED: (Owner.FALLBACK, FallbackCommand.HOLD, QueueAction.NEW_EPOCH, False),
    Mode.SAFE_HOLD: (Owner.FALLBACK, FallbackCommand.HOLD, QueueAction.PURGE, False),
    Mode.REPLAN_OR_RETREAT: (Owner.PLANNER, FallbackCommand.RETREAT, QueueAction.PURGE, False),
    Mode.CONTACT_FALLBACK: (Owner.CONTACT, FallbackCommand.RETREAT, QueueAction.PURGE, False),
    Mode.CONTROLLER_STOP: (Owner.SAFETY, FallbackCommand.STOP, QueueAction.PURGE, False),
    Mode.HUMAN_RECOVERY: (Owner.HUMAN, FallbackCommand.HOLD, QueueAction.PURGE, False),
    Mode.E_STOP: (Owner.SAFETY, FallbackCommand.STOP, QueueAction.PURGE, False),
}


@pytest.mark.parametrize("mode", list(Mode))
def test_each_state_card(mode: Mode) -> None:
    card = MODES[mode]
    assert (card.owner, card.command, card.queue, card.accepts_proposals) == CARDS[mode]
    assert card.recovery


# --- every sequence, judged by the table -------------------------------------------------------


class FallbackTable(RuleBasedStateMachine):
    """Random sequences of triggers and requests; each step is predicted from EXPECTED."""

    def __init__(self) -> None:
        super().__init__()
        self.fsm = machine()
        self.mode = Mode.RUNNING
        self.timing_count = 0

    def _moved(self, target: Mode) -> None:
        self.mode, self.timing_count = target, 0

    @rule(code=st.sampled_from(sorted(R)), immediate=st.booleans())
    def fire(self, code: R, immediate: bool) -> None:
        transition = self.fsm.fire(code, immediate)
        rule_ = EXPECTED.get(code)
        if rule_ is None or self.mode not in rule_.sources:
            assert transition is None
            return
        if rule_.debounce > 1 and not immediate:
            self.timing_count += 1
            if self.timing_count < rule_.debounce:
                assert transition is None
                return
        assert transition == Transition(self.mode, rule_.to, code)
        self._moved(rule_.to)

    @rule()
    def healthy_chunk(self) -> None:
        self.fsm.clear_debounce()
        self.timing_count = 0

    @rule(valid=st.booleans(), ok=st.booleans())
    def recover(self, valid: bool, ok: bool) -> None:
        result = self.fsm.recover(valid, ok)
        if self.mode in RECOVERABLE and (self.mode is not Mode.CONTROLLER_STOP or ok):
            assert isinstance(result, Transition)
            self._moved(Mode.RUNNING if valid else Mode.DEGRADED)
        else:
            assert isinstance(result, str)

    @rule()
    def release(self) -> None:
        if isinstance(self.fsm.release(), Transition):
            assert self.mode is Mode.HUMAN_RECOVERY
            self._moved(Mode.SAFE_HOLD)

    @rule(clear=st.booleans())
    def reset(self, clear: bool) -> None:
        if isinstance(self.fsm.reset(clear), Transition):
            assert self.mode is Mode.E_STOP and clear
            self._moved(Mode.SAFE_HOLD)

    @precondition(lambda self: self.mode is Mode.DEGRADED)
    @rule()
    def validated(self) -> None:
        assert self.fsm.validated() is not None
        self._moved(Mode.RUNNING)

    @invariant()
    def the_machine_is_where_the_table_says(self) -> None:
        assert self.fsm.mode is self.mode
        assert (self.fsm.cause is None) == (self.mode is Mode.RUNNING)


TestFallbackTable = FallbackTable.TestCase
