"""Scenarios for the way back to work: every recovery validates, nothing given up is resumed,
contact is never re-entered without evidence, and a session that ends does so at once."""

from __future__ import annotations

from tools.scenarios.base import EVIDENCE, Q0, ScenarioSpec, chunk, event, observation, offer
from tools.scenarios.base import state as st

_NO_POLICY_MOTION = {"kind": "tick", "command": "setpoint", "owner": "policy"}


def aborted_task_is_not_resumed() -> ScenarioSpec:
    return ScenarioSpec(
        name="aborted_task_is_not_resumed",
        description="A task aborted during a takeover stays given up: recovery does not "
                    "validate it, it leaves ABORT only for IDLE, and VALIDATE from IDLE waits "
                    "for the task to start again instead of resuming the suspended phase.",
        events=[st(0, list(Q0)), event(10, "operator", action="takeover"),
                event(20, "operator", action="abort"),
                event(30, "operator", action="accept_recovery"),
                event(40, "phase", to="IDLE"), event(50, "phase", to="VALIDATE"),
                observation(60, "O1"),
                chunk(62, "C1", 1, "O1", 60, first=64, actions=[list(Q0)] * 3, epoch=1)],
        until=80,
        expect=[
            {"kind": "transition", "machine": "task", "from": "HUMAN_RECOVERY", "to": "ABORT",
             "t": 20},
            {"kind": "transition", "machine": "fallback", "to": "RUNNING", "t": 30},
            {"kind": "transition", "machine": "task", "from": "ABORT", "to": "IDLE", "t": 40},
            {"kind": "transition", "machine": "task", "from": "IDLE", "to": "VALIDATE",
             "t": 50},
            {"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
             "reasons_include": ["PHASE_MISMATCH"]},
            {"kind": "tick", "t": 78, "phase": "VALIDATE", "owner": "fallback"},
        ],
        forbid=[{"kind": "transition", "machine": "task", "from": "VALIDATE",
                 "to": "PRE_CONTACT"},
                {"kind": "transition", "machine": "task", "from": "ABORT", "to": "VALIDATE"},
                _NO_POLICY_MOTION],
    )


def aborted_task_stays_aborted() -> ScenarioSpec:
    return ScenarioSpec(
        name="aborted_task_stays_aborted",
        description="An aborted task is not mirrored into SAFE_HOLD by a release or a later "
                    "takeover, and no recovery validates it back to work; a hold request still "
                    "holds the arm (the fallback machine), the task stays ABORT.",
        events=[st(0, list(Q0)), event(10, "operator", action="takeover"),
                event(20, "operator", action="abort"),
                event(24, "operator", action="release"),
                event(30, "operator", action="accept_recovery"),
                event(40, "phase", to="PRE_CONTACT"),
                event(50, "phase", to="SAFE_HOLD", by="policy")],
        until=60,
        expect=[
            {"kind": "transition", "machine": "fallback", "from": "HUMAN_RECOVERY",
             "to": "SAFE_HOLD", "trigger": "OPERATOR_RELEASE", "t": 24},
            {"kind": "transition", "machine": "fallback", "from": "SAFE_HOLD", "to": "RUNNING",
             "t": 30},
            {"kind": "transition", "machine": "task", "t": 40, "accepted": False,
             "requested": "PRE_CONTACT", "trigger": "GUARD_FAILED"},
            {"kind": "transition", "machine": "fallback", "from": "RUNNING", "to": "SAFE_HOLD",
             "trigger": "HOLD_REQUESTED", "t": 50},
            {"kind": "tick", "t": 58, "phase": "ABORT", "mode": "SAFE_HOLD"},
        ],
        forbid=[*({"kind": "transition", "machine": "task", "from": "ABORT", "to": phase}
                  for phase in ("SAFE_HOLD", "HUMAN_RECOVERY", "VALIDATE", "PRE_CONTACT")),
                {"kind": "transition", "machine": "task", "t_min": 21,
                 "trigger": "GUARD_PASSED"},
                _NO_POLICY_MOTION],
    )


def contact_resumes_before_contact() -> ScenarioSpec:
    return ScenarioSpec(
        name="contact_resumes_before_contact",
        description="A task held during CONTACT validates back into PRE_CONTACT, not CONTACT: "
                    "the evidence it entered contact with is stale after a hold, so contact "
                    "is entered again only through its guard.",
        phase="CONTACT",
        events=[st(0, list(Q0)), event(10, "phase", to="SAFE_HOLD"),
                event(20, "operator", action="accept_recovery"),
                event(30, "phase", to="CONTACT", evidence=EVIDENCE)],
        until=40,
        expect=[
            {"kind": "transition", "machine": "task", "from": "CONTACT", "to": "SAFE_HOLD",
             "t": 10},
            {"kind": "transition", "machine": "task", "from": "VALIDATE", "to": "PRE_CONTACT",
             "trigger": "GUARD_PASSED", "t": 20},
            {"kind": "tick", "t": 22, "phase": "PRE_CONTACT"},
            {"kind": "transition", "machine": "task", "from": "PRE_CONTACT", "to": "CONTACT",
             "trigger": "GUARD_PASSED", "t": 30},
        ],
        forbid=[{"kind": "tick", "phase": "CONTACT", "t_min": 10, "t_max": 29},
                {"kind": "transition", "machine": "task", "from": "VALIDATE", "to": "CONTACT"}],
    )


def validate_to_contact_needs_evidence() -> ScenarioSpec:
    return ScenarioSpec(
        name="validate_to_contact_needs_evidence",
        description="VALIDATE may lead to any work phase, but into CONTACT only with the same "
                    "four pieces of evidence PRE_CONTACT → CONTACT needs.",
        events=[st(0, list(Q0)), event(10, "phase", to="RETREAT"),
                event(20, "phase", to="IDLE"), event(30, "phase", to="VALIDATE"),
                event(40, "phase", to="CONTACT", evidence={}),
                event(50, "phase", to="CONTACT", evidence=EVIDENCE)],
        until=60,
        expect=[
            {"kind": "transition", "machine": "task", "t": 40, "accepted": False,
             "trigger": "GUARD_FAILED", "requested": "CONTACT",
             "missing_evidence": list(EVIDENCE)},
            {"kind": "tick", "t": 42, "phase": "VALIDATE"},
            {"kind": "transition", "machine": "task", "t": 50, "from": "VALIDATE",
             "to": "CONTACT", "trigger": "GUARD_PASSED"},
        ],
        forbid=[{"kind": "tick", "phase": "CONTACT", "t_max": 49}],
    )


def watchdog_without_any_state() -> ScenarioSpec:
    return ScenarioSpec(
        name="watchdog_without_any_state",
        description="The state watchdog runs from the first tick: feedback that never arrives "
                    "is caught like feedback that stops (WATCHDOG → CONTROLLER_STOP).",
        timing={"state_timeout_ms": 20},
        events=[], until=40,
        expect=[{"kind": "transition", "machine": "fallback", "from": "RUNNING",
                 "to": "CONTROLLER_STOP", "trigger": "WATCHDOG", "t": 22},
                {"kind": "tick", "t": 22, "command": "stop", "owner": "safety"}],
        forbid=[{"kind": "transition", "machine": "fallback", "t_max": 20}],
    )


def rejected_handshake_degrades_at_once() -> ScenarioSpec:
    bad = offer(chunk_horizon=0, policy_checkpoint="act-unknown")
    return ScenarioSpec(
        name="rejected_handshake_degrades_at_once",
        description="A rejected handshake ends the session at once (DEGRADED), even when its "
                    "first reason is MALFORMED, which on a chunk is debounced; the next ACCEPT "
                    "is a new session: new epoch, VALIDATE, and old-epoch chunks refused.",
        events=[st(0, list(Q0)), event(10, "handshake", offer=bad),
                event(20, "handshake", offer=offer(queue_epoch=1)),
                observation(30, "O1"),
                chunk(32, "C1", 1, "O1", 30, first=34, actions=[list(Q0)] * 3)],
        until=40,
        expect=[
            {"kind": "handshake", "t": 10, "decision": "REJECT",
             "reasons_include": ["MALFORMED", "CHECKPOINT_NOT_ALLOWED"]},
            {"kind": "transition", "machine": "fallback", "from": "RUNNING", "to": "DEGRADED",
             "trigger": "MALFORMED", "t": 10},
            {"kind": "handshake", "t": 20, "decision": "ACCEPT", "queue_epoch": 1},
            {"kind": "transition", "machine": "task", "from": "PRE_CONTACT", "to": "VALIDATE",
             "t": 20},
            {"kind": "transition", "machine": "fallback", "from": "DEGRADED", "to": "RUNNING",
             "t": 20},
            {"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
             "reasons_include": ["OLD_QUEUE_EPOCH"]},
        ],
        forbid=[_NO_POLICY_MOTION],
    )


def every_recovery_validates() -> ScenarioSpec:
    return ScenarioSpec(
        name="every_recovery_validates",
        description="DEGRADED returns to RUNNING only through VALIDATE, also when a controller "
                    "fault in between made the way back a recovery from CONTROLLER_STOP.",
        events=[st(0, list(Q0)), event(10, "link", status="down"),
                event(20, "controller", status="fault"), event(30, "link", status="up"),
                event(32, "handshake", offer=offer(queue_epoch=1)),
                event(40, "controller", status="ok"), st(45, list(Q0)),
                event(50, "operator", action="accept_recovery")],
        until=60,
        expect=[
            {"kind": "transition", "machine": "fallback", "from": "DEGRADED",
             "to": "CONTROLLER_STOP", "trigger": "CONTROLLER_FAULT", "t": 20},
            {"kind": "transition", "machine": "fallback", "from": "CONTROLLER_STOP",
             "to": "RUNNING", "trigger": "RECOVERY_ACCEPTED", "t": 50},
            {"kind": "transition", "machine": "task", "from": "PRE_CONTACT", "to": "VALIDATE",
             "trigger": "RECOVERY_ACCEPTED", "t": 50},
            {"kind": "transition", "machine": "task", "from": "VALIDATE", "to": "PRE_CONTACT",
             "t": 50},
        ],
    )


SCENARIOS = [aborted_task_is_not_resumed, aborted_task_stays_aborted,
             contact_resumes_before_contact,
             validate_to_contact_needs_evidence, watchdog_without_any_state,
             rejected_handshake_degrades_at_once, every_recovery_validates]
