"""Scenarios for session and context: handshake, allowlist, skill, phase, mode, calibration."""

from __future__ import annotations

from tools.scenarios.base import Q0, ScenarioSpec, chunk, event, observation, offer, ramp
from tools.scenarios.base import state as st


def _start() -> list[dict]:
    return [st(0, list(Q0)), observation(0, "O1")]


def handshake_required_after_reconnect() -> ScenarioSpec:
    return ScenarioSpec(
        name="handshake_required_after_reconnect",
        description="A lost link ends the session: DEGRADED, a new epoch, and no chunk is "
                    "admitted until a new handshake is ACCEPTed and VALIDATE passes. "
                    "Reconnecting never waives the check.",
        events=[
            *_start(), chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 10)),
            st(30, ramp(1, 2)[1]), event(40, "link", status="down"),
            event(60, "link", status="up"), observation(60, "O2"),
            chunk(65, "C2", 2, "O2", 60, first=70, actions=ramp(3, 6), epoch=1),
            event(70, "handshake", offer=offer(queue_epoch=1)), observation(72, "O3"),
            chunk(90, "C3", 3, "O3", 72, first=90, actions=ramp(3, 6), epoch=1),
        ],
        until=120,
        expect=[
            {"kind": "transition", "machine": "fallback", "from": "RUNNING", "to": "DEGRADED",
             "trigger": "LINK_LOST", "t": 40},
            {"kind": "queue", "action": "new_epoch", "queue_epoch": 1, "t": 40},
            {"kind": "tick", "t": 50, "command": "hold", "owner": "fallback", "mode": "DEGRADED",
             "reason": "LINK_LOST"},
            {"kind": "chunk", "chunk_id": "C2", "decision": "rejected",
             "reasons_include": ["HANDSHAKE_REQUIRED"]},
            {"kind": "handshake", "decision": "ACCEPT", "t": 70},
            {"kind": "transition", "machine": "task", "to": "VALIDATE", "t": 70},
            {"kind": "transition", "machine": "task", "from": "VALIDATE", "to": "PRE_CONTACT"},
            {"kind": "transition", "machine": "fallback", "from": "DEGRADED", "to": "RUNNING"},
            {"kind": "chunk", "chunk_id": "C3", "decision": "accepted", "queue_epoch": 1},
        ],
        forbid=[{"kind": "tick", "t_min": 40, "sent.chunk_id": "C1"},
                {"kind": "tick", "sent.chunk_id": "C2"}],
    )


def handshake_matrix() -> ScenarioSpec:
    """Seed §6.3: change one field at a time; ACCEPT with a fingerprint or a bounded REJECT."""
    rows = [
        ("compatible", offer(queue_epoch=1), "ACCEPT", []),
        ("old checkpoint", offer(policy_checkpoint="act-insert-2025-12"), "REJECT",
         ["CHECKPOINT_NOT_ALLOWED"]),
        ("reordered observation keys",
         offer(observation_keys=["scene_rgb", "wrist_rgb", "joint_pos", "wrench"]), "REJECT",
         ["SCHEMA_MISMATCH"]),
        ("stale calibration", offer(calibration_epoch="cal-11"), "REJECT",
         ["CALIBRATION_MISMATCH"]),
        ("wrong action unit", offer(action_units="deg"), "REJECT", ["SCHEMA_MISMATCH"]),
        ("unsupported controller mode", offer(controller_mode="torque"), "REJECT",
         ["CONTROLLER_MODE_MISMATCH"]),
        ("unknown reason code", offer(reason_codes=["DUPLICATE", "VIBES_OFF"]), "REJECT",
         ["PROTOCOL_MISMATCH"]),
        ("no common protocol", offer(protocol=[3, 4]), "REJECT", ["PROTOCOL_MISMATCH"]),
        ("server restart with an old queue epoch", offer(queue_epoch=0), "REJECT",
         ["OLD_QUEUE_EPOCH"]),
        ("other skill version", offer(skill_version="2.0.0"), "REJECT", ["SKILL_MISMATCH"]),
        ("missing chunk_horizon", {k: v for k, v in offer().items() if k != "chunk_horizon"},
         "REJECT", ["MALFORMED"]),
    ]
    events = [*_start(), event(10, "link", status="down"), event(12, "link", status="up")]
    expect = []
    for index, (_, body, decision, reasons) in enumerate(rows):
        t = 20 + 10 * index
        events.append(event(t, "handshake", offer=body))
        matcher = {"kind": "handshake", "t": t, "decision": decision}
        if reasons:
            matcher["reasons"] = reasons
        expect.append(matcher)
    expect.append({"kind": "transition", "machine": "fallback", "from": "DEGRADED",
                   "to": "RUNNING", "t": 20})
    expect.append({"kind": "transition", "machine": "fallback", "from": "RUNNING",
                   "to": "DEGRADED", "trigger": "CHECKPOINT_NOT_ALLOWED", "t": 30})
    return ScenarioSpec(
        name="handshake_matrix",
        description="The seed's handshake test matrix, one field changed at a time after a "
                    "reconnect: " + "; ".join(r[0] for r in rows) + ". Each answer is ACCEPT "
                    "with a fingerprint or REJECT with bounded reasons and an empty queue.",
        events=events, until=130, expect=expect,
        forbid=[{"kind": "tick", "command": "setpoint"}],
    )


def _context_case(name: str, description: str, reason: str, degrades: bool, **fields):
    def build() -> ScenarioSpec:
        expect = [{"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
                   "reasons": [reason]}]
        forbid = [{"kind": "tick", "sent.chunk_id": "C1"}]
        trigger = {"kind": "transition", "machine": "fallback", "to": "DEGRADED",
                   "trigger": reason}
        (expect if degrades else forbid).append(trigger)
        return ScenarioSpec(
            name=name, description=description,
            events=[*_start(), chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 6),
                                     **fields)],
            until=40, expect=expect, forbid=forbid,
        )
    return build


checkpoint_not_allowed = _context_case(
    "checkpoint_not_allowed",
    "A chunk from a checkpoint outside the allowlist is refused, and the session that let it "
    "through is dropped (DEGRADED).", "CHECKPOINT_NOT_ALLOWED", True,
    policy_checkpoint="act-insert-rogue")
config_mismatch = _context_case(
    "config_mismatch",
    "A chunk whose config hash differs from the accepted handshake is refused (DEGRADED).",
    "CONFIG_MISMATCH", True, config_hash="cfg-0000")
skill_mismatch = _context_case(
    "skill_mismatch",
    "A chunk for another skill version is refused; it was made for another skill, so it says "
    "nothing about the current motion and raises no fallback.", "SKILL_MISMATCH", False,
    skill_version="3.0.0")
phase_mismatch = _context_case(
    "phase_mismatch",
    "A chunk proposed for another task phase is refused (and raises no fallback).",
    "PHASE_MISMATCH", False, task_phase="FREE_SPACE")
controller_mode_mismatch = _context_case(
    "controller_mode_mismatch",
    "A chunk for another controller mode is refused; a proposer may never switch the "
    "controller mode (DEGRADED).", "CONTROLLER_MODE_MISMATCH", True,
    controller_mode="joint_torque")
calibration_mismatch = _context_case(
    "calibration_mismatch",
    "A chunk made under another calibration epoch is refused (DEGRADED).",
    "CALIBRATION_MISMATCH", True, calibration_epoch="cal-11")


def allowlisted_but_not_this_session() -> ScenarioSpec:
    return ScenarioSpec(
        name="allowlisted_but_not_this_session",
        description="An allowlisted checkpoint that is not the one this session accepted is "
                    "still refused: the handshake fixes the tuple for the session.",
        events=[*_start(), chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 6),
                                 policy_checkpoint="act-insert-2026-06",
                                 config_hash="cfg-77a1")],
        until=30,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
                 "reasons": ["CHECKPOINT_NOT_ALLOWED", "CONFIG_MISMATCH"]}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


def no_authority() -> ScenarioSpec:
    return ScenarioSpec(
        name="no_authority",
        description="The policy asks for SAFE_HOLD (it may); from then on the fallback owner "
                    "accepts no proposals: NO_AUTHORITY. In RETREAT the planner owns motion "
                    "and refuses learned chunks too.",
        events=[
            *_start(), event(10, "phase", to="SAFE_HOLD", by="policy"),
            chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 6)),
            event(30, "operator", action="accept_recovery"),
            event(32, "phase", to="RETREAT", by="fsm"), observation(34, "O2"),
            chunk(40, "C2", 2, "O2", 34, first=40, actions=ramp(1, 6), task_phase="RETREAT",
                  epoch=1),
        ],
        until=50,
        expect=[
            {"kind": "transition", "machine": "task", "to": "SAFE_HOLD",
             "trigger": "HOLD_REQUESTED", "t": 10},
            {"kind": "transition", "machine": "fallback", "to": "SAFE_HOLD",
             "trigger": "HOLD_REQUESTED", "t": 10},
            {"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
             "reasons_include": ["NO_AUTHORITY"]},
            {"kind": "chunk", "chunk_id": "C2", "decision": "rejected",
             "reasons": ["NO_AUTHORITY"]},
            {"kind": "tick", "t": 44, "command": "retreat", "owner": "planner",
             "reason": "PHASE_OWNER"},
        ],
        forbid=[{"kind": "tick", "command": "setpoint"}],
    )


SCENARIOS = [handshake_required_after_reconnect, handshake_matrix, checkpoint_not_allowed,
             config_mismatch, skill_mismatch, phase_mismatch, controller_mode_mismatch,
             calibration_mismatch, allowlisted_but_not_this_session, no_authority]
