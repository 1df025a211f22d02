"""The worked stale-chunk trace (a chunk that arrives after the robot entered contact, and its
resend after a reconnect), shifted by +50 ms so that C40 fits before it."""

from __future__ import annotations

from tools.scenarios.base import (
    EVIDENCE,
    ScenarioSpec,
    chunk,
    event,
    observation,
    offer,
    q_at,
    ramp,
    state,
)

SHIFT = 50  # seed time 0 ms is scenario time 50 ms


def seed_stale_chunk() -> ScenarioSpec:
    events = [state(0, q_at(0)), observation(0, "O40"),
              chunk(30, "C40", 40, "O40", 0, first=30, actions=ramp(1, 10))]
    for k, t in enumerate(range(40, 121, 10), start=1):
        events.append(state(t, q_at(k)))
        if t == SHIFT:
            events.append(observation(SHIFT, "O41"))  # seed 0 ms: O41 in PRE_CONTACT
    events.append(event(120, "phase", to="CONTACT", by="fsm", evidence=EVIDENCE))  # seed 70
    pressed = q_at(9)
    pressed[2] += 0.03  # the contact controller moved the arm: the state C41 assumed is gone
    events += [state(t, pressed, force_residual=6.0) for t in (130, 140, 150)]
    c41 = chunk(153, "C41", 41, "O41", SHIFT, first=160, actions=ramp(3, 8),
                inference_end=136, server_send=137)  # seed 86 ms done, 103 ms arrives
    resend = dict(c41, t=290)  # seed 240 ms: the reconnect resends C41
    events += [
        c41,
        event(175, "force", residual=22.5),  # seed 125: residual leaves the band
        event(210, "operator", action="accept_recovery"),  # seed 160: new epoch
        event(212, "phase", to="RETREAT", by="fsm", evidence={}),
        event(250, "link", status="down"),
        event(280, "link", status="up"),
        event(280, "handshake", offer=offer(chunk_horizon=10, queue_epoch=2)),
        resend,
    ]
    return ScenarioSpec(
        name="seed_stale_chunk",
        description=(
            "Seed §4 (times +50 ms): C41 is made for PRE_CONTACT from O41, arrives after the "
            "contact transition and is refused for PHASE_MISMATCH + STATE_DIVERGED; the "
            "contact owner holds on the underrun; a force residual out of band selects the "
            "contact fallback; recovery starts a new epoch; the resend after reconnection is "
            "ignored for OLD_QUEUE_EPOCH + DUPLICATE. No action of C41 ever runs."
        ),
        events=events, until=320,
        expect=[
            {"kind": "chunk", "chunk_id": "C40", "decision": "accepted"},
            {"kind": "tick", "t": 76, "command": "setpoint", "owner": "policy",
             "sent.chunk_id": "C40"},
            {"kind": "transition", "machine": "task", "from": "PRE_CONTACT", "to": "CONTACT",
             "t": 120},
            {"kind": "queue", "action": "purge", "t": 120},
            {"kind": "chunk", "chunk_id": "C41", "t": 153, "decision": "rejected",
             "reasons": ["PHASE_MISMATCH", "STATE_DIVERGED"]},
            {"kind": "tick", "t": 158, "command": "contact", "owner": "contact",
             "reason": "UNDERRUN", "phase": "CONTACT"},
            {"kind": "transition", "machine": "fallback", "from": "RUNNING",
             "to": "CONTACT_FALLBACK", "trigger": "CONTACT_ANOMALY", "t": 175},
            {"kind": "queue", "action": "new_epoch", "queue_epoch": 1, "t": 210},
            {"kind": "transition", "machine": "fallback", "to": "RUNNING",
             "trigger": "RECOVERY_ACCEPTED", "t": 210},
            {"kind": "handshake", "decision": "ACCEPT", "t": 280},
            {"kind": "chunk", "chunk_id": "C41", "t": 290, "decision": "ignored",
             "reasons": ["OLD_QUEUE_EPOCH", "DUPLICATE"]},
        ],
        forbid=[
            {"kind": "tick", "sent.chunk_id": "C41"},
            {"kind": "chunk", "chunk_id": "C41", "decision": "accepted"},
        ],
    )


SCENARIOS = [seed_stale_chunk]
