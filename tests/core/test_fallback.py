"""The fallback state machine (docs/contract.md §6): examples of debounce, recovery,
E_STOP and refusal triggers. Every rule, from every state, is in test_fallback_table.py."""

from __future__ import annotations

import pytest

from assurance.fallback import (
    IRRELEVANT,
    MODES,
    FallbackMachine,
    Mode,
    ModeCard,
    Owner,
    refusal_trigger,
)
from assurance.reasons import ReasonCode as R

TIMING = (R.OBSERVATION_STALE, R.EXPIRED, R.REORDERED, R.TRIM_FORBIDDEN, R.CLOCK_INVALID,
          R.UNKNOWN_OBSERVATION, R.MALFORMED, R.NONFINITE)


def machine(mode: Mode = Mode.RUNNING, degrade_after: int = 3) -> FallbackMachine:
    return FallbackMachine(degrade_after=degrade_after, mode=mode)


def test_every_mode_has_a_card() -> None:
    assert set(MODES) == set(Mode)
    assert all(isinstance(card, ModeCard) for card in MODES.values())
    assert [m for m in Mode if MODES[m].accepts_proposals] == [Mode.RUNNING]
    assert MODES[Mode.E_STOP].owner is Owner.SAFETY


@pytest.mark.parametrize("mode", [m for m in Mode if m is not Mode.E_STOP])
def test_e_stop_is_reachable_from_every_state(mode: Mode) -> None:
    fsm = machine(mode)
    transition = fsm.fire(R.E_STOP)
    assert transition is not None and transition.source is mode
    assert fsm.mode is Mode.E_STOP and fsm.cause is R.E_STOP


@pytest.mark.parametrize("trigger", list(R))
def test_nothing_but_reset_leaves_e_stop(trigger: R) -> None:
    fsm = machine(Mode.E_STOP)
    assert fsm.fire(trigger) is None
    assert isinstance(fsm.recover(True, True), str)
    assert isinstance(fsm.release(), str)
    assert fsm.validated() is None
    assert fsm.mode is Mode.E_STOP


def test_reset_needs_the_e_stop_cleared_and_goes_to_safe_hold() -> None:
    fsm = machine(Mode.E_STOP)
    assert isinstance(fsm.reset(estop_clear=False), str) and fsm.mode is Mode.E_STOP
    transition = fsm.reset(estop_clear=True)
    assert transition.target is Mode.SAFE_HOLD and transition.trigger is R.OPERATOR_RESET
    assert isinstance(machine().reset(estop_clear=True), str)


def test_degraded_returns_to_running_only_through_validated() -> None:
    fsm = machine(Mode.DEGRADED)
    for trigger in R:
        if trigger is not R.E_STOP:
            probe = machine(Mode.DEGRADED)
            probe.fire(trigger)
            assert probe.mode is not Mode.RUNNING
    assert isinstance(fsm.recover(True, True), str) and fsm.mode is Mode.DEGRADED
    transition = fsm.validated()
    assert transition.target is Mode.RUNNING and fsm.mode is Mode.RUNNING and fsm.cause is None
    assert fsm.validated() is None  # only from DEGRADED


# --- debounce ----------------------------------------------------------------------------------


def test_timing_refusals_need_degrade_after_consecutive_occurrences() -> None:
    fsm = machine(degrade_after=3)
    assert fsm.fire(R.EXPIRED) is None
    assert fsm.fire(R.EXPIRED) is None
    transition = fsm.fire(R.EXPIRED)
    assert transition.target is Mode.DEGRADED and fsm.cause is R.EXPIRED


def test_timing_refusals_share_one_counter() -> None:
    fsm = machine(degrade_after=len(TIMING))
    for trigger in TIMING[:-1]:
        assert fsm.fire(trigger) is None
    assert fsm.fire(TIMING[-1]).target is Mode.DEGRADED


def test_clear_debounce_restarts_the_count() -> None:
    fsm = machine(degrade_after=2)
    fsm.fire(R.EXPIRED)
    fsm.clear_debounce()
    assert fsm.fire(R.REORDERED) is None
    assert fsm.fire(R.REORDERED) is not None


def test_non_timing_triggers_are_not_debounced() -> None:
    fsm = machine(degrade_after=5)
    assert fsm.fire(R.CONFIG_MISMATCH).target is Mode.DEGRADED


def test_degrade_after_must_be_at_least_one() -> None:
    with pytest.raises(ValueError):
        FallbackMachine(degrade_after=0)


# --- recovery ----------------------------------------------------------------------------------


def test_controller_stop_recovers_only_when_the_controller_is_ok() -> None:
    fsm = machine(Mode.CONTROLLER_STOP)
    assert isinstance(fsm.recover(handshake_valid=True, controller_ok=False), str)
    assert fsm.mode is Mode.CONTROLLER_STOP
    assert fsm.recover(handshake_valid=True, controller_ok=True).target is Mode.RUNNING


@pytest.mark.parametrize("mode", [Mode.SAFE_HOLD, Mode.REPLAN_OR_RETREAT,
                                  Mode.CONTACT_FALLBACK, Mode.HUMAN_RECOVERY])
@pytest.mark.parametrize(("valid", "target"), [(True, Mode.RUNNING), (False, Mode.DEGRADED)])
def test_recover_target_depends_on_the_handshake(mode: Mode, valid: bool, target: Mode) -> None:
    transition = machine(mode).recover(handshake_valid=valid, controller_ok=False)
    assert transition.target is target and transition.trigger is R.RECOVERY_ACCEPTED


@pytest.mark.parametrize("mode", [Mode.RUNNING, Mode.DEGRADED, Mode.E_STOP])
def test_nothing_to_recover_from(mode: Mode) -> None:
    fsm = machine(mode)
    assert isinstance(fsm.recover(True, True), str) and fsm.mode is mode


def test_release_ends_a_takeover_in_safe_hold_only() -> None:
    fsm = machine(Mode.HUMAN_RECOVERY)
    assert fsm.release().target is Mode.SAFE_HOLD
    assert isinstance(fsm.release(), str)


def test_a_less_severe_trigger_never_pulls_out_of_a_more_severe_state() -> None:
    fsm = machine(Mode.CONTROLLER_STOP)
    for trigger in (R.STATE_DIVERGED, R.LINK_LOST, R.INFEASIBLE, R.CONTACT_ANOMALY, R.WATCHDOG):
        assert fsm.fire(trigger) is None
    assert fsm.mode is Mode.CONTROLLER_STOP


# --- refusal triggers --------------------------------------------------------------------------


@pytest.mark.parametrize("irrelevant", [R.PHASE_MISMATCH, R.OLD_QUEUE_EPOCH, R.DUPLICATE,
                                        R.NO_AUTHORITY, R.HANDSHAKE_REQUIRED])
def test_irrelevant_refusals_raise_no_trigger(irrelevant: R) -> None:
    assert irrelevant in IRRELEVANT
    assert refusal_trigger((R.STATE_DIVERGED, irrelevant, R.EXPIRED)) is None


def test_the_most_severe_refusal_reason_is_the_trigger() -> None:
    assert refusal_trigger((R.EXPIRED, R.STATE_DIVERGED)) is R.STATE_DIVERGED
    assert refusal_trigger((R.MALFORMED, R.CONFIG_MISMATCH, R.EXPIRED)) is R.CONFIG_MISMATCH
    assert refusal_trigger((R.NONFINITE,)) is R.NONFINITE
    assert refusal_trigger(()) is None
    assert refusal_trigger((R.GUARD_FAILED,)) is None
