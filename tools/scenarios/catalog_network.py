"""A policy link with delay, jitter, a lost chunk, reordering and a duplicate, in free space."""

from __future__ import annotations

from tools.scenarios.base import Q0, ScenarioSpec, chunk, observation, q_at, ramp
from tools.scenarios.base import state as st


def network_faults_free_space() -> ScenarioSpec:
    fs = {"task_phase": "FREE_SPACE"}
    c5 = chunk(145, "C5", 5, "O5", 130, first=150, actions=ramp(12, 6), **fs)
    states = [st(t, q_at(min((t - 20) // 10, 11))) for t in range(30, 221, 10)]
    return ScenarioSpec(
        name="network_faults_free_space",
        description="Delay (C1 arrives 20 ms after its observation), jitter (C2 arrives after "
                    "its first action was due: trimmed in free space), drop (C3 never "
                    "arrives: the queue runs dry and the robot holds), reorder (C5 overtakes "
                    "C4, which is then REORDERED) and a duplicate of C5 (ignored).",
        phase="FREE_SPACE",
        events=[
            st(0, list(Q0)), observation(0, "O1"), *states,
            chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 6), **fs),
            observation(40, "O2"),
            chunk(75, "C2", 2, "O2", 40, first=70, actions=ramp(6, 6), **fs),
            observation(80, "O3"), observation(120, "O4"), observation(130, "O5"),
            c5,
            chunk(148, "C4", 4, "O4", 120, first=140, actions=ramp(11, 6), **fs),
            dict(c5, t=160),
        ],
        until=220,
        expect=[
            {"kind": "chunk", "chunk_id": "C1", "decision": "accepted"},
            {"kind": "chunk", "chunk_id": "C2", "decision": "trimmed", "trimmed": 1},
            {"kind": "tick", "t": 80, "sent.chunk_id": "C2", "sent.index": 1},
            {"kind": "tick", "t": 140, "command": "hold", "reason": "UNDERRUN"},
            {"kind": "chunk", "chunk_id": "C5", "decision": "accepted", "t": 145},
            {"kind": "chunk", "chunk_id": "C4", "decision": "rejected", "reasons": ["REORDERED"]},
            {"kind": "chunk", "chunk_id": "C5", "decision": "ignored", "t": 160,
             "reasons": ["DUPLICATE"]},
            {"kind": "tick", "t": 150, "sent.chunk_id": "C5", "sent.index": 0},
        ],
        forbid=[{"kind": "tick", "sent.chunk_id": "C4"},
                {"kind": "tick", "sent.chunk_id": "C2", "sent.index": 0},
                {"kind": "transition", "machine": "fallback"}],
    )


SCENARIOS = [network_faults_free_space]
