"""Scenarios for content and identity: malformed, non-finite, schema, duplicates, order, epochs."""

from __future__ import annotations

from tools.scenarios.base import DELTA, DROP, Q0, ScenarioSpec, chunk, observation, q_at, ramp
from tools.scenarios.base import state as st


def _start() -> list[dict]:
    return [st(0, list(Q0)), observation(0, "O1")]


def accepted_and_executed() -> ScenarioSpec:
    return ScenarioSpec(
        name="accepted_and_executed",
        description="A fresh, in-context chunk is accepted, runs action by action on its own "
                    "grid, and the queue running dry turns into a hold at the measured state.",
        events=[*_start(), chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 8))],
        until=110,
        expect=[
            {"kind": "request", "t": 0, "observation_id": "O1"},
            {"kind": "chunk", "chunk_id": "C1", "decision": "accepted", "reasons": [],
             "projection_distance": 0.0, "queue_depth": 8},
            {"kind": "tick", "t": 20, "command": "setpoint", "owner": "policy",
             "sent.chunk_id": "C1", "sent.index": 0},
            {"kind": "tick", "t": 58, "sent.chunk_id": "C1", "sent.index": 3},
            {"kind": "tick", "t": 98, "sent.chunk_id": "C1", "sent.index": 7},
            {"kind": "tick", "t": 100, "command": "hold", "owner": "fallback", "sent": None,
             "reason": "UNDERRUN"},
        ],
        forbid=[{"kind": "tick", "t_max": 18, "command": "setpoint"}],
    )


def malformed_chunk() -> ScenarioSpec:
    return ScenarioSpec(
        name="malformed_chunk",
        description="Chunks that cannot be decoded are refused as MALFORMED (no traceback, no "
                    "motion); a good chunk afterwards is admitted.",
        events=[
            *_start(),
            chunk(10, "C1", 1, "O1", 0, first=20, actions=DROP),
            chunk(12, "C2", 2, "O1", 0, first=20, actions=[[0.0] * 6, [0.0] * 5]),
            chunk(14, "C3", "three", "O1", 0, first=20, actions=ramp(1, 4)),
            chunk(16, "C4", 4, "O1", 0, first=20, actions=ramp(1, 4),
                  replacement_policy="sideways"),
            chunk(18, "C5", 5, "O1", 0, first=20, actions=ramp(1, 4), action_dt=-10),
            chunk(20, "C6", 6, "O1", 0, first=20, actions=ramp(1, 4)),
        ],
        timing={"degrade_after": 6},
        until=40,
        expect=[
            {"kind": "chunk", "chunk_id": cid, "decision": "rejected", "reasons": ["MALFORMED"]}
            for cid in ("C1", "C2", "C3", "C4", "C5")
        ] + [{"kind": "chunk", "chunk_id": "C6", "decision": "accepted"}],
        forbid=[{"kind": "tick", "sent.chunk_id": cid} for cid in ("C1", "C2", "C3", "C4", "C5")],
    )


def nonfinite_chunk() -> ScenarioSpec:
    bad = ramp(1, 4)
    bad[2][1] = float("nan")
    worse = ramp(1, 4)
    worse[0][0] = float("inf")
    return ScenarioSpec(
        name="nonfinite_chunk",
        description="NaN or infinite actions or times are refused as NONFINITE.",
        events=[
            *_start(),
            chunk(10, "C1", 1, "O1", 0, first=20, actions=bad),
            chunk(12, "C2", 2, "O1", 0, first=20, actions=worse),
            chunk(14, "C3", 3, "O1", 0, first=float("inf"), actions=ramp(1, 4)),
        ],
        until=30,
        expect=[
            {"kind": "chunk", "chunk_id": "C1", "decision": "rejected", "reasons": ["NONFINITE"]},
            {"kind": "chunk", "chunk_id": "C2", "decision": "rejected", "reasons": ["NONFINITE"]},
            {"kind": "chunk", "chunk_id": "C3", "decision": "rejected",
             "reasons_include": ["NONFINITE"]},
        ],
        forbid=[{"kind": "tick", "command": "setpoint"}],
    )


def schema_mismatch() -> ScenarioSpec:
    narrow = [row[:5] for row in ramp(1, 4)]
    return ScenarioSpec(
        name="schema_mismatch",
        description="Actions of the wrong dimension, units or frame are refused as "
                    "SCHEMA_MISMATCH; the server no longer matches its handshake, so the "
                    "session is lost (DEGRADED) and later chunks also need a new handshake.",
        events=[
            *_start(),
            chunk(10, "C1", 1, "O1", 0, first=20, actions=narrow),
            chunk(12, "C2", 2, "O1", 0, first=20, actions=ramp(1, 4), action_units="deg"),
            chunk(14, "C3", 3, "O1", 0, first=20, actions=ramp(1, 4), action_frame="tcp"),
        ],
        until=30,
        expect=[
            {"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
             "reasons": ["SCHEMA_MISMATCH"]},
            {"kind": "transition", "machine": "fallback", "to": "DEGRADED",
             "trigger": "SCHEMA_MISMATCH", "t": 10},
        ] + [{"kind": "chunk", "chunk_id": cid, "decision": "rejected",
              "reasons_include": ["SCHEMA_MISMATCH", "HANDSHAKE_REQUIRED"]}
             for cid in ("C2", "C3")],
        forbid=[{"kind": "tick", "command": "setpoint"}],
    )


def duplicate_ignored() -> ScenarioSpec:
    c1 = chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 8))
    return ScenarioSpec(
        name="duplicate_ignored",
        description="The same chunk id and payload again is ignored idempotently: nothing "
                    "changes, however many times it arrives.",
        events=[*_start(), c1, dict(c1, t=25, server_send=21), dict(c1, t=31)],
        until=60,
        expect=[
            {"kind": "chunk", "chunk_id": "C1", "t": 20, "decision": "accepted"},
            {"kind": "chunk", "chunk_id": "C1", "t": 25, "decision": "ignored",
             "reasons": ["DUPLICATE"]},
            {"kind": "chunk", "chunk_id": "C1", "t": 31, "decision": "ignored",
             "reasons": ["DUPLICATE"]},
            {"kind": "tick", "t": 58, "sent.chunk_id": "C1", "sent.index": 3},
        ],
        forbid=[{"kind": "chunk", "chunk_id": "C1", "t_min": 21, "decision": "accepted"}],
    )


def observation_answered() -> ScenarioSpec:
    return ScenarioSpec(
        name="observation_answered",
        description="A second chunk (a new id) citing an observation that an admitted chunk "
                    "already answered answers nothing pending: refused OBSERVATION_ANSWERED "
                    "before any gate, with no fallback; the queue runs on the first answer, and "
                    "the answer to the next observation is admitted as usual.",
        events=[*_start(), chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 8)),
                st(30, q_at(1)), chunk(30, "C2", 2, "O1", 0, first=40, actions=ramp(3, 8)),
                observation(40, "O2"), st(40, q_at(2)), st(50, q_at(3)),
                chunk(60, "C3", 3, "O2", 0, first=70, actions=ramp(6, 8))],
        until=80,
        expect=[
            {"kind": "chunk", "chunk_id": "C1", "t": 20, "decision": "accepted"},
            {"kind": "chunk", "chunk_id": "C2", "t": 30, "decision": "rejected",
             "reasons": ["OBSERVATION_ANSWERED"]},
            {"kind": "tick", "t": 40, "sent.chunk_id": "C1"},
            {"kind": "chunk", "chunk_id": "C3", "t": 60, "decision": "replaced"},
        ],
        forbid=[{"kind": "transition"}, {"kind": "tick", "sent.chunk_id": "C2"}],
    )


def id_conflict() -> ScenarioSpec:
    other = ramp(1, 8)
    other[4][0] += 0.001
    return ScenarioSpec(
        name="id_conflict",
        description="The same chunk id with another payload is an ID_CONFLICT: refused, and a "
                    "server that reuses ids loses the session (DEGRADED).",
        events=[*_start(), chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 8)),
                chunk(30, "C1", 2, "O1", 0, first=40, actions=other)],
        until=50,
        expect=[
            {"kind": "chunk", "chunk_id": "C1", "t": 30, "decision": "rejected",
             "reasons": ["ID_CONFLICT"]},
            {"kind": "transition", "machine": "fallback", "from": "RUNNING", "to": "DEGRADED",
             "trigger": "ID_CONFLICT"},
            {"kind": "tick", "t": 32, "command": "hold", "mode": "DEGRADED"},
        ],
        forbid=[{"kind": "tick", "t_min": 30, "sent.chunk_id": "C1"}],
    )


def reordered_sequence() -> ScenarioSpec:
    states = [st(t, q_at(k)) for k, t in enumerate(range(10, 70, 10), start=1)]
    return ScenarioSpec(
        name="reordered_sequence",
        description="A chunk whose sequence is not newer than the last admitted one in this "
                    "epoch arrived out of order: REORDERED.",
        events=[*_start(), observation(10, "O2"),
                chunk(30, "C2", 2, "O2", 10, first=30, actions=ramp(3, 8)), *states,
                chunk(35, "C1", 1, "O1", 0, first=40, actions=ramp(4, 6))],
        until=60,
        expect=[
            {"kind": "chunk", "chunk_id": "C2", "decision": "accepted"},
            {"kind": "chunk", "chunk_id": "C1", "decision": "rejected", "reasons": ["REORDERED"]},
        ],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


def queue_epochs() -> ScenarioSpec:
    return ScenarioSpec(
        name="queue_epochs",
        description="Chunks made for an earlier queue epoch are OLD_QUEUE_EPOCH whatever their "
                    "sequence; an epoch the client never issued is FUTURE_QUEUE_EPOCH.",
        epoch=3,
        events=[*_start(),
                chunk(10, "C1", 99, "O1", 0, first=20, actions=ramp(1, 4), epoch=2),
                chunk(12, "C2", 1, "O1", 0, first=20, actions=ramp(1, 4), epoch=4),
                chunk(14, "C3", 1, "O1", 0, first=20, actions=ramp(1, 4), epoch=3)],
        until=30,
        expect=[
            {"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
             "reasons": ["OLD_QUEUE_EPOCH"]},
            {"kind": "chunk", "chunk_id": "C2", "decision": "rejected",
             "reasons": ["FUTURE_QUEUE_EPOCH"]},
            {"kind": "chunk", "chunk_id": "C3", "decision": "accepted", "queue_epoch": 3},
        ],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}, {"kind": "tick", "sent.chunk_id": "C2"},
                {"kind": "transition", "machine": "fallback"}],
    )


def unknown_observation() -> ScenarioSpec:
    return ScenarioSpec(
        name="unknown_observation",
        description="A chunk conditioned on an observation this client never sent is refused: "
                    "the client's own record of its observations is authoritative.",
        events=[*_start(), chunk(20, "C1", 1, "O9", 0, first=20, actions=ramp(1, 4))],
        until=30,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
                 "reasons": ["UNKNOWN_OBSERVATION"]}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


SCENARIOS = [accepted_and_executed, malformed_chunk, nonfinite_chunk, schema_mismatch,
             duplicate_ignored, observation_answered, id_conflict, reordered_sequence, queue_epochs,
             unknown_observation]
_ = DELTA
