"""Scenarios for time: clock provenance, staleness, expiry, trimming and long tails."""

from __future__ import annotations

from tools.scenarios.base import Q0, ScenarioSpec, chunk, event, observation, q_at, ramp
from tools.scenarios.base import state as st


def _start() -> list[dict]:
    return [st(0, list(Q0)), observation(0, "O1")]


def clock_invalid_then_synced() -> ScenarioSpec:
    server = 1000.0  # the server's clock reads 1000 ms more than the client's
    times = {"observation_event_time": server, "observation_arrival_time": server + 1,
             "inference_start": server + 5, "inference_end": server + 15,
             "server_send": server + 16, "clock_domain": "server"}
    return ScenarioSpec(
        name="clock_invalid_then_synced",
        description="Times in the server's clock without a measured offset and round-trip "
                    "bound are CLOCK_INVALID; once a clock sync is measured the same kind of "
                    "chunk is translated (with the added uncertainty) and admitted.",
        events=[
            *_start(),
            chunk(20, "C1", 1, "O1", 0, first=server + 20, actions=ramp(1, 6), **times),
            event(25, "clock_sync", domain="server", offset_ms=-server, round_trip_ms=2),
            chunk(30, "C2", 2, "O1", 0, first=server + 30, actions=ramp(1, 6), **times),
        ],
        until=60,
        expect=[
            {"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
             "reasons": ["CLOCK_INVALID"]},
            {"kind": "chunk", "chunk_id": "C2", "decision": "accepted"},
            {"kind": "tick", "t": 30, "sent.chunk_id": "C2", "sent.index": 0},
        ],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


def observation_stale() -> ScenarioSpec:
    return ScenarioSpec(
        name="observation_stale",
        description="Inference started 70 ms after the observation; the phase allows 60 ms: "
                    "OBSERVATION_STALE, even though its actions are not yet too old.",
        events=[*_start(), chunk(80, "C1", 1, "O1", 0, first=80, actions=ramp(1, 4),
                                 inference_start=70, inference_end=78)],
        until=90,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
                 "reasons": ["OBSERVATION_STALE"]}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


def expired_prefix_pre_contact() -> ScenarioSpec:
    return ScenarioSpec(
        name="expired_prefix_pre_contact",
        description="Three actions were due before the chunk arrived (negative slack). "
                    "PRE_CONTACT forbids trimming, so the whole chunk is EXPIRED.",
        events=[*_start(), chunk(45, "C1", 1, "O1", 0, first=20, actions=ramp(1, 8))],
        until=60,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
                 "reasons": ["EXPIRED"]}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


def trimmed_free_space() -> ScenarioSpec:
    return ScenarioSpec(
        name="trimmed_free_space",
        description="The same late chunk in FREE_SPACE, whose contract allows trimming: the "
                    "expired prefix is dropped, the suffix passes every gate and is projected "
                    "again from the current hold.",
        phase="FREE_SPACE",
        events=[*_start(), chunk(45, "C1", 1, "O1", 0, first=20, actions=ramp(1, 8),
                                 task_phase="FREE_SPACE")],
        until=110,
        expect=[
            {"kind": "chunk", "chunk_id": "C1", "decision": "trimmed", "trimmed": 3},
            {"kind": "tick", "t": 48, "command": "hold", "reason": "UNDERRUN"},
            {"kind": "tick", "t": 50, "sent.chunk_id": "C1", "sent.index": 3},
        ],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1", "sent.index": 0},
                {"kind": "tick", "sent.chunk_id": "C1", "sent.index": 2}],
    )


def trim_forbidden_gripper_event() -> ScenarioSpec:
    rows = [[*q, 0.0 if j < 2 else 1.0] for j, q in enumerate(ramp(1, 8))]
    return ScenarioSpec(
        name="trim_forbidden_gripper_event",
        description="Trimming would delete the gripper closing inside the late prefix: "
                    "TRIM_FORBIDDEN, the chunk is refused whole.",
        phase="FREE_SPACE", gripper=True,
        events=[*_start(), chunk(45, "C1", 1, "O1", 0, first=20, actions=rows,
                                 task_phase="FREE_SPACE")],
        until=60,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
                 "reasons": ["TRIM_FORBIDDEN"]}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


def trim_forbidden_phase_marker() -> ScenarioSpec:
    return ScenarioSpec(
        name="trim_forbidden_phase_marker",
        description="The chunk marks a phase transition at action 1, inside the late prefix: "
                    "TRIM_FORBIDDEN.",
        phase="FREE_SPACE",
        events=[*_start(), chunk(45, "C1", 1, "O1", 0, first=20, actions=ramp(1, 8),
                                 task_phase="FREE_SPACE", phase_markers=[1])],
        until=60,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
                 "reasons": ["TRIM_FORBIDDEN"]}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


def expired_entirely() -> ScenarioSpec:
    return ScenarioSpec(
        name="expired_entirely",
        description="None of the chunk's actions can run before expiring: EXPIRED, even where "
                    "trimming is allowed.",
        phase="FREE_SPACE",
        events=[*_start(), chunk(195, "C1", 1, "O1", 0, first=20, actions=ramp(1, 8),
                                 task_phase="FREE_SPACE", inference_start=5)],
        until=200,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
                 "reasons": ["EXPIRED"]}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


def long_tail_expires_when_due() -> ScenarioSpec:
    return ScenarioSpec(
        name="long_tail_expires_when_due",
        description="A chunk whose tail would outlive the 120 ms age bound is admitted; the "
                    "tail is dropped when due (never executed) and the robot holds.",
        events=[*_start(), *[st(t, q_at(k)) for k, t in enumerate(range(30, 121, 10), 1)],
                chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 15))],
        until=130,
        expect=[
            {"kind": "chunk", "chunk_id": "C1", "decision": "accepted"},
            {"kind": "tick", "t": 118, "sent.chunk_id": "C1", "sent.index": 9},
            {"kind": "queue", "t": 120, "action": "expire", "chunk_id": "C1", "dropped": 5},
            {"kind": "tick", "t": 120, "command": "hold", "reason": "UNDERRUN"},
        ],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1", "sent.index": 10}],
    )


def degrade_after_repeated_stale() -> ScenarioSpec:
    def late(t: int, cid: str, seq: int) -> dict:
        return chunk(t, cid, seq, "O1", 0, first=t, actions=ramp(1, 4), inference_start=70)
    return ScenarioSpec(
        name="degrade_after_repeated_stale",
        description="One stale chunk is a refusal; three in a row (the debounce) mean the "
                    "link is not keeping up: DEGRADED until a new handshake.",
        events=[*_start(), late(80, "C1", 1), late(82, "C2", 2), late(84, "C3", 3)],
        until=90,
        expect=[
            {"kind": "chunk", "chunk_id": "C3", "reasons": ["OBSERVATION_STALE"]},
            {"kind": "transition", "machine": "fallback", "to": "DEGRADED",
             "trigger": "OBSERVATION_STALE", "t": 84},
        ],
        forbid=[{"kind": "transition", "machine": "fallback", "t_max": 83}],
    )


SCENARIOS = [clock_invalid_then_synced, observation_stale, expired_prefix_pre_contact,
             trimmed_free_space, trim_forbidden_gripper_event, trim_forbidden_phase_marker,
             expired_entirely, long_tail_expires_when_due, degrade_after_repeated_stale]
