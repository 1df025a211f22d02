"""Scenarios for authority: OOD, contact anomaly, controller, watchdog, human, E-stop, guards."""

from __future__ import annotations

from tools.scenarios.base import EVIDENCE, Q0, ScenarioSpec, chunk, event, observation, q_at, ramp
from tools.scenarios.base import state as st


def _running() -> list[dict]:
    """A chunk in progress (C1, actions due 20..110 ms) with states that track it."""
    return [st(0, list(Q0)), observation(0, "O1"),
            chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 10)),
            *[st(t, q_at((t - 20) // 10)) for t in range(30, 121, 10)]]


def ood_safe_hold() -> ScenarioSpec:
    return ScenarioSpec(
        name="ood_safe_hold",
        description="An OOD score under the phase threshold changes nothing; one above it "
                    "requests SAFE_HOLD, which the fallback owner grants at once.",
        events=[*_running(), event(30, "ood", score=0.5), event(40, "ood", score=0.93)],
        until=60,
        expect=[
            {"kind": "transition", "machine": "fallback", "from": "RUNNING", "to": "SAFE_HOLD",
             "trigger": "OOD", "t": 40},
            {"kind": "tick", "t": 38, "sent.chunk_id": "C1"},
            {"kind": "tick", "t": 40, "command": "hold", "owner": "fallback", "reason": "OOD"},
        ],
        forbid=[{"kind": "tick", "t_min": 40, "sent.chunk_id": "C1"},
                {"kind": "transition", "machine": "fallback", "t_max": 39}],
    )


def contact_anomaly_fallback() -> ScenarioSpec:
    return ScenarioSpec(
        name="contact_anomaly_fallback",
        description="In CONTACT the impedance law owns motion; a force residual outside the "
                    "band selects the force-aware retreat (CONTACT_FALLBACK).",
        phase="CONTACT",
        events=[st(0, list(Q0), force_residual=3.0), st(10, list(Q0), force_residual=9.0),
                st(20, list(Q0), force_residual=-16.0)],
        until=30,
        expect=[
            {"kind": "tick", "t": 0, "command": "contact", "owner": "contact"},
            {"kind": "transition", "machine": "fallback", "to": "CONTACT_FALLBACK",
             "trigger": "CONTACT_ANOMALY", "t": 20},
            {"kind": "tick", "t": 20, "command": "retreat", "owner": "contact",
             "reason": "CONTACT_ANOMALY"},
        ],
    )


def controller_reject_and_recovery() -> ScenarioSpec:
    return ScenarioSpec(
        name="controller_reject_and_recovery",
        description="The controller rejects a setpoint: CONTROLLER_STOP, nothing is streamed. "
                    "Recovery needs the controller to report ok first, then the operator: a "
                    "new epoch purges whatever was queued before.",
        events=[*_running(), event(40, "controller", status="reject"),
                event(50, "operator", action="accept_recovery"),
                event(60, "controller", status="ok"),
                event(70, "operator", action="accept_recovery")],
        until=80,
        expect=[
            {"kind": "transition", "machine": "fallback", "to": "CONTROLLER_STOP",
             "trigger": "CONTROLLER_REJECT", "t": 40},
            {"kind": "tick", "t": 42, "command": "stop", "owner": "safety",
             "reason": "CONTROLLER_REJECT"},
            {"kind": "transition", "machine": "fallback", "t": 50, "accepted": False,
             "trigger": "GUARD_FAILED"},
            {"kind": "transition", "machine": "fallback", "from": "CONTROLLER_STOP",
             "to": "RUNNING", "trigger": "RECOVERY_ACCEPTED", "t": 70},
            {"kind": "queue", "action": "new_epoch", "queue_epoch": 1, "t": 70},
        ],
        forbid=[{"kind": "tick", "t_min": 40, "sent.chunk_id": "C1"}],
    )


def invalid_feedback_fault() -> ScenarioSpec:
    return ScenarioSpec(
        name="invalid_feedback_fault",
        description="A state sample with a NaN joint is invalid feedback: the controller is "
                    "no longer trusted (CONTROLLER_FAULT → CONTROLLER_STOP).",
        events=[*_running(), st(45, [0.0, float("nan"), 1.5, -1.87, -1.57, 0.0])],
        until=60,
        expect=[{"kind": "transition", "machine": "fallback", "to": "CONTROLLER_STOP",
                 "trigger": "CONTROLLER_FAULT", "t": 45}],
        forbid=[{"kind": "tick", "t_min": 45, "sent.chunk_id": "C1"}],
    )


def state_implausible_holds_where_plausible() -> ScenarioSpec:
    glitched = q_at(2)
    glitched[0] += 0.5  # 0.5 rad in 5 ms: 100 rad/s, a reading no joint of this arm can make
    return ScenarioSpec(
        name="state_implausible_holds_where_plausible",
        description="A state sample 0.5 rad off 5 ms after a plausible one (a reading glitch: "
                    "no joint moves 100 rad/s) is STATE_IMPLAUSIBLE: it never becomes the "
                    "measured state, and the fallback holds where the arm was last plausibly "
                    "measured (SAFE_HOLD). The samples after it are plausible again.",
        events=[*_running(), st(45, glitched)],
        until=70,
        expect=[
            {"kind": "transition", "machine": "fallback", "from": "RUNNING", "to": "SAFE_HOLD",
             "trigger": "STATE_IMPLAUSIBLE", "t": 45},
            {"kind": "tick", "t": 44, "sent.chunk_id": "C1"},
            {"kind": "tick", "t": 46, "command": "hold", "owner": "fallback",
             "reason": "STATE_IMPLAUSIBLE"},
        ],
        forbid=[{"kind": "tick", "t_min": 45, "sent.chunk_id": "C1"},
                {"kind": "transition", "machine": "fallback", "t_max": 44},
                {"kind": "transition", "machine": "fallback", "t_min": 46}],
    )


def watchdog_state_timeout() -> ScenarioSpec:
    early = [st(10, list(Q0)), st(20, list(Q0))]
    events = [e for e in _running() if not (e["kind"] == "state" and e["t"] > 50)] + early
    return ScenarioSpec(
        name="watchdog_state_timeout",
        description="With a 20 ms state watchdog configured, state samples that stop after "
                    "50 ms trip WATCHDOG (CONTROLLER_STOP) at the first tick past 70 ms.",
        timing={"state_timeout_ms": 20},
        events=events, until=90,
        expect=[{"kind": "transition", "machine": "fallback", "to": "CONTROLLER_STOP",
                 "trigger": "WATCHDOG", "t": 72}],
        forbid=[{"kind": "transition", "machine": "fallback", "t_max": 70},
                {"kind": "tick", "t_min": 72, "sent.chunk_id": "C1"}],
    )


def recorder_failed() -> ScenarioSpec:
    return ScenarioSpec(
        name="recorder_failed",
        description="The shell can no longer write the run's record (a full disk): the core "
                    "stops the arm (RECORDER_FAILED -> CONTROLLER_STOP) from the tick of that "
                    "instant on, and the queued actions never run. A later failure while "
                    "E_STOP already stops the arm changes nothing and is logged as such.",
        events=[*_running(), event(40, "recorder", fault="no_space"),
                event(60, "operator", action="estop"),
                event(70, "recorder", fault="io_error")],
        until=80,
        expect=[
            {"kind": "transition", "machine": "fallback", "from": "RUNNING",
             "to": "CONTROLLER_STOP", "trigger": "RECORDER_FAILED", "t": 40,
             "detail": "the run's record cannot be written: no_space"},
            {"kind": "tick", "t": 40, "command": "stop", "owner": "safety",
             "reason": "RECORDER_FAILED"},
            {"kind": "transition", "machine": "fallback", "from": "E_STOP", "to": "E_STOP",
             "trigger": "RECORDER_FAILED", "accepted": False, "t": 70},
        ],
        forbid=[{"kind": "tick", "t_min": 40, "sent.chunk_id": "C1"}],
    )


def human_takeover_and_release() -> ScenarioSpec:
    return ScenarioSpec(
        name="human_takeover_and_release",
        description="The operator takes over: the human owns motion and no proposal is "
                    "accepted; release hands authority to a validated hold, not to the policy; "
                    "accept_recovery validates and starts a new epoch.",
        events=[*_running(), event(40, "operator", action="takeover"),
                observation(45, "O2"),
                chunk(50, "C2", 2, "O2", 45, first=50, actions=ramp(3, 6)),
                event(60, "operator", action="release"),
                event(80, "operator", action="accept_recovery")],
        until=90,
        expect=[
            {"kind": "transition", "machine": "fallback", "to": "HUMAN_RECOVERY",
             "trigger": "HUMAN_TAKEOVER", "t": 40},
            {"kind": "transition", "machine": "task", "to": "HUMAN_RECOVERY", "t": 40},
            {"kind": "tick", "t": 42, "owner": "human"},
            {"kind": "chunk", "chunk_id": "C2", "decision": "rejected",
             "reasons_include": ["NO_AUTHORITY"]},
            {"kind": "transition", "machine": "fallback", "from": "HUMAN_RECOVERY",
             "to": "SAFE_HOLD", "trigger": "OPERATOR_RELEASE", "t": 60},
            {"kind": "tick", "t": 62, "command": "hold", "owner": "fallback"},
            {"kind": "transition", "machine": "fallback", "from": "SAFE_HOLD", "to": "RUNNING",
             "trigger": "RECOVERY_ACCEPTED", "t": 80},
            {"kind": "transition", "machine": "task", "from": "VALIDATE", "to": "PRE_CONTACT",
             "t": 80},
            {"kind": "queue", "action": "new_epoch", "queue_epoch": 1, "t": 80},
        ],
        forbid=[{"kind": "tick", "t_min": 40, "sent.chunk_id": "C1"},
                {"kind": "tick", "sent.chunk_id": "C2"}],
    )


def estop_wins_everywhere() -> ScenarioSpec:
    return ScenarioSpec(
        name="estop_wins_everywhere",
        description="E_STOP is reachable from every state and nothing overrules it: not a "
                    "chunk, not a takeover, not a recovery. Reset leaves it only toward a "
                    "validated hold, and only once the controller no longer asserts it.",
        events=[*_running(), event(30, "operator", action="estop"),
                observation(32, "O2"),
                chunk(34, "C2", 2, "O2", 32, first=34, actions=ramp(2, 4)),
                event(36, "operator", action="takeover"),
                event(38, "operator", action="accept_recovery"),
                event(40, "operator", action="reset"),
                event(50, "operator", action="takeover"),
                event(60, "operator", action="estop"),
                event(70, "controller", status="estop"),
                event(80, "operator", action="reset"),
                event(90, "controller", status="ok"),
                event(100, "operator", action="reset")],
        until=110,
        expect=[
            {"kind": "transition", "machine": "fallback", "from": "RUNNING", "to": "E_STOP",
             "trigger": "E_STOP", "t": 30},
            {"kind": "tick", "t": 32, "command": "stop", "owner": "safety", "reason": "E_STOP"},
            {"kind": "chunk", "chunk_id": "C2", "reasons_include": ["NO_AUTHORITY"]},
            {"kind": "transition", "machine": "fallback", "t": 36, "accepted": False},
            {"kind": "transition", "machine": "fallback", "t": 38, "accepted": False},
            {"kind": "transition", "machine": "fallback", "from": "E_STOP", "to": "SAFE_HOLD",
             "trigger": "OPERATOR_RESET", "t": 40},
            {"kind": "transition", "machine": "fallback", "from": "HUMAN_RECOVERY",
             "to": "E_STOP", "t": 60},
            {"kind": "transition", "machine": "fallback", "t": 80, "accepted": False,
             "trigger": "GUARD_FAILED"},
            {"kind": "transition", "machine": "fallback", "from": "E_STOP", "to": "SAFE_HOLD",
             "t": 100},
        ],
        forbid=[{"kind": "tick", "t_min": 30, "command": "setpoint"}],
    )


def guard_failed_missing_evidence() -> ScenarioSpec:
    partial = dict(EVIDENCE, force_fresh=False)
    return ScenarioSpec(
        name="guard_failed_missing_evidence",
        description="PRE_CONTACT → CONTACT needs pose tolerance, controller-mode ack, a fresh "
                    "force signal and a valid contact envelope: with one missing the guard "
                    "fails and the phase stays; with all four it passes.",
        events=[st(0, list(Q0)), event(10, "phase", to="CONTACT", evidence=partial),
                event(20, "phase", to="CONTACT", evidence=EVIDENCE)],
        until=30,
        expect=[
            {"kind": "transition", "machine": "task", "t": 10, "accepted": False,
             "trigger": "GUARD_FAILED", "requested": "CONTACT", "to": "PRE_CONTACT",
             "missing_evidence": ["force_fresh"]},
            {"kind": "tick", "t": 12, "phase": "PRE_CONTACT"},
            {"kind": "transition", "machine": "task", "t": 20, "from": "PRE_CONTACT",
             "to": "CONTACT", "trigger": "GUARD_PASSED"},
        ],
    )


def policy_cannot_authorize() -> ScenarioSpec:
    return ScenarioSpec(
        name="policy_cannot_authorize",
        description="A request by the policy can never authorize a guarded transition, even "
                    "with every piece of evidence claimed true; it may only ask for SAFE_HOLD.",
        events=[st(0, list(Q0)),
                event(10, "phase", to="CONTACT", evidence=EVIDENCE, by="policy"),
                event(20, "phase", to="SAFE_HOLD", by="policy")],
        until=30,
        expect=[
            {"kind": "transition", "machine": "task", "t": 10, "accepted": False,
             "trigger": "NO_AUTHORITY", "requested": "CONTACT"},
            {"kind": "transition", "machine": "task", "t": 20, "to": "SAFE_HOLD",
             "trigger": "HOLD_REQUESTED"},
            {"kind": "transition", "machine": "fallback", "t": 20, "to": "SAFE_HOLD"},
        ],
        forbid=[{"kind": "tick", "phase": "CONTACT"}],
    )


SCENARIOS = [ood_safe_hold, contact_anomaly_fallback, controller_reject_and_recovery,
             invalid_feedback_fault, state_implausible_holds_where_plausible,
             watchdog_state_timeout, recorder_failed,
             human_takeover_and_release, estop_wins_everywhere, guard_failed_missing_evidence,
             policy_cannot_authorize]
