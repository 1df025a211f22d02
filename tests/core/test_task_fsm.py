"""The task FSM (docs/contract.md §6): phases advance on evidence, never on confidence."""

from __future__ import annotations

import pytest

from assurance.reasons import ReasonCode as R
from skills.phases import (
    DEFAULT_EXECUTORS,
    SUSPENDED,
    WORK_PHASES,
    Executor,
    PhaseBook,
    TaskPhase,
)
from skills.task_fsm import CONTACT_EVIDENCE, EDGES, Requester, TaskMachine

P = TaskPhase
FULL = dict.fromkeys(CONTACT_EVIDENCE, True)


def test_contact_needs_all_four_pieces_of_evidence() -> None:
    assert set(CONTACT_EVIDENCE) == {"pose_within_tolerance", "controller_mode_ack",
                                     "force_fresh", "contact_envelope_valid"}
    fsm = TaskMachine(P.PRE_CONTACT)
    decision = fsm.request(P.CONTACT, FULL, Requester.FSM)
    assert decision.accepted and decision.trigger is R.GUARD_PASSED
    assert fsm.phase is P.CONTACT


@pytest.mark.parametrize("bad", [None, False, "true", 1, 1.0, [True]])
@pytest.mark.parametrize("key", CONTACT_EVIDENCE)
def test_evidence_must_be_exactly_true(key: str, bad: object) -> None:
    fsm = TaskMachine(P.PRE_CONTACT)
    evidence = {**FULL, key: bad}
    if bad is None:
        del evidence[key]
    decision = fsm.request(P.CONTACT, evidence, Requester.FSM)
    assert not decision.accepted and decision.trigger is R.GUARD_FAILED
    assert decision.missing_evidence == (key,)
    assert fsm.phase is P.PRE_CONTACT


def test_missing_evidence_lists_every_missing_key() -> None:
    decision = TaskMachine(P.PRE_CONTACT).request(
        P.CONTACT, {"force_fresh": True}, Requester.FSM)
    assert decision.missing_evidence == ("pose_within_tolerance", "controller_mode_ack",
                                         "contact_envelope_valid")


def test_the_policy_can_never_authorize_a_guarded_transition() -> None:
    fsm = TaskMachine(P.PRE_CONTACT)
    decision = fsm.request(P.CONTACT, FULL, Requester.POLICY)
    assert not decision.accepted and decision.trigger is R.NO_AUTHORITY
    assert fsm.phase is P.PRE_CONTACT


@pytest.mark.parametrize("target", [P.FREE_SPACE, P.RETREAT])
def test_the_policy_cannot_move_along_unguarded_edges_either(target: P) -> None:
    fsm = TaskMachine(P.PRE_CONTACT)
    assert fsm.request(target, {}, Requester.POLICY).reasons == (R.NO_AUTHORITY,)
    assert fsm.phase is P.PRE_CONTACT


@pytest.mark.parametrize("phase", sorted(WORK_PHASES | {P.IDLE, P.VALIDATE}))
def test_the_policy_may_request_safe_hold(phase: P) -> None:
    fsm = TaskMachine(phase)
    decision = fsm.request(P.SAFE_HOLD, {}, Requester.POLICY)
    assert decision.accepted and decision.trigger is R.HOLD_REQUESTED
    assert fsm.phase is P.SAFE_HOLD


def test_a_policy_hold_request_does_not_end_a_human_takeover() -> None:
    fsm = TaskMachine(P.HUMAN_RECOVERY)
    fsm.request(P.SAFE_HOLD, {}, Requester.POLICY)
    assert fsm.phase is P.HUMAN_RECOVERY


@pytest.mark.parametrize(("source", "target"), [
    (source, target) for source in P for target in P
    if target not in EDGES[source] and target is not P.SAFE_HOLD
])
def test_illegal_edges_fail_their_guard(source: P, target: P) -> None:
    fsm = TaskMachine(source)
    decision = fsm.request(target, FULL, Requester.FSM)
    assert not decision.accepted and R.GUARD_FAILED in decision.reasons
    assert fsm.phase is source


def test_without_authority_the_fsm_may_only_move_to_suspended_phases() -> None:
    fsm = TaskMachine(P.FREE_SPACE)
    assert fsm.request(P.PRE_CONTACT, {}, Requester.FSM, fsm_has_authority=False).reasons == (
        R.NO_AUTHORITY,)
    hold = TaskMachine(P.SAFE_HOLD)
    assert hold.request(P.ABORT, {}, Requester.FSM, fsm_has_authority=False).accepted


def test_an_illegal_policy_request_lists_both_reasons() -> None:
    decision = TaskMachine(P.IDLE).request(P.CONTACT, {}, Requester.POLICY)
    assert decision.reasons == (R.NO_AUTHORITY, R.GUARD_FAILED)


def test_resume_after_validation_returns_to_the_suspended_work_phase() -> None:
    fsm = TaskMachine(P.PRE_CONTACT)
    assert fsm.suspend(P.SAFE_HOLD, R.STATE_DIVERGED).source is P.PRE_CONTACT
    assert fsm.suspend(P.HUMAN_RECOVERY, R.HUMAN_TAKEOVER) is not None
    assert fsm.begin_validation(R.RECOVERY_ACCEPTED).target is P.VALIDATE
    assert fsm.begin_validation(R.RECOVERY_ACCEPTED) is None  # already validating
    decision = fsm.finish_validation()
    assert decision.target is P.PRE_CONTACT and fsm.phase is P.PRE_CONTACT
    assert fsm.resume_phase is None


def test_validation_from_a_work_phase_resumes_it() -> None:
    fsm = TaskMachine(P.FREE_SPACE)
    fsm.begin_validation(R.HANDSHAKE_ACCEPTED)
    assert fsm.finish_validation().target is P.FREE_SPACE


def test_finish_validation_without_a_suspended_phase_does_nothing() -> None:
    fsm = TaskMachine(P.IDLE)
    fsm.request(P.VALIDATE, {}, Requester.FSM)
    assert fsm.finish_validation() is None and fsm.phase is P.VALIDATE
    assert TaskMachine(P.FREE_SPACE).finish_validation() is None


def test_suspend_to_the_current_phase_is_a_no_op() -> None:
    assert TaskMachine(P.SAFE_HOLD).suspend(P.SAFE_HOLD, R.OOD) is None


# --- phase cards -------------------------------------------------------------------------------


def test_every_phase_has_a_default_card() -> None:
    book = PhaseBook()
    assert set(DEFAULT_EXECUTORS) == set(P)
    assert {p for p in P if book.card(p).takes_proposals} == {P.FREE_SPACE, P.PRE_CONTACT,
                                                              P.CONTACT}
    assert not WORK_PHASES & SUSPENDED


def test_a_configured_card_overrides_the_default() -> None:
    card = PhaseBook.make_card(P.RETREAT, PhaseBook().card(P.RETREAT).policy, Executor.POLICY)
    assert PhaseBook({P.RETREAT: card}).card(P.RETREAT).takes_proposals
    assert not PhaseBook().card(P.RETREAT).takes_proposals
