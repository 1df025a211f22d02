"""Scenarios for the queue and feasibility: divergence, projection, replace, append, blend,
underrun."""

from __future__ import annotations

from tools.scenarios.base import Q0, ScenarioSpec, chunk, observation, q_at, ramp
from tools.scenarios.base import state as st


def _tracking(until: int, start: int = 30) -> list[dict]:
    """State samples that follow the approach path one action behind the command."""
    return [st(t, q_at((t - 20) // 10)) for t in range(start, until + 1, 10)]


def _start() -> list[dict]:
    return [st(0, list(Q0)), observation(0, "O1")]


def state_diverged_safe_hold() -> ScenarioSpec:
    pushed = list(Q0)
    pushed[0] += 0.05
    return ScenarioSpec(
        name="state_diverged_safe_hold",
        description="The measured state moved 0.05 rad away from what the chunk assumes (the "
                    "phase allows 0.02): STATE_DIVERGED rejects even time-valid actions, and "
                    "the fallback holds (SAFE_HOLD).",
        events=[*_start(), st(15, pushed),
                chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 8))],
        until=40,
        expect=[
            {"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
             "reasons": ["STATE_DIVERGED"], "divergence": 0.048},
            {"kind": "transition", "machine": "fallback", "from": "RUNNING", "to": "SAFE_HOLD",
             "trigger": "STATE_DIVERGED", "t": 20},
            {"kind": "transition", "machine": "task", "to": "SAFE_HOLD", "t": 20},
            {"kind": "tick", "t": 22, "command": "hold", "owner": "fallback",
             "reason": "STATE_DIVERGED"},
        ],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


def infeasible_replan_or_retreat() -> ScenarioSpec:
    rows = ramp(1, 8)
    for row in rows[4:]:
        row[0] += 0.2  # a 0.2 rad jump inside the chunk: no projection within 0.01 rad fixes it
    return ScenarioSpec(
        name="infeasible_replan_or_retreat",
        description="A chunk that no projection within the phase's max_projection can make "
                    "admissible is INFEASIBLE: refused whole, and the planner takes over "
                    "(REPLAN_OR_RETREAT).",
        events=[*_start(), chunk(20, "C1", 1, "O1", 0, first=20, actions=rows)],
        until=40,
        expect=[
            {"kind": "chunk", "chunk_id": "C1", "decision": "rejected", "reasons": ["INFEASIBLE"]},
            {"kind": "transition", "machine": "fallback", "to": "REPLAN_OR_RETREAT",
             "trigger": "INFEASIBLE"},
            {"kind": "tick", "t": 22, "command": "retreat", "owner": "planner"},
        ],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


def projected_within_bound() -> ScenarioSpec:
    rows = [[round(Q0[i] + 1.5 * (j + 1) * (q_at(1)[i] - Q0[i]), 6) for i in range(6)]
            for j in range(8)]
    return ScenarioSpec(
        name="projected_within_bound",
        description="The chunk starts 1.5x faster than the acceleration limit allows from a "
                    "hold; projection ramps it up (distance 0.002 rad, inside the phase's 0.01) "
                    "and the projected actions are what runs.",
        events=[*_start(), chunk(20, "C1", 1, "O1", 0, first=20, actions=rows)],
        until=40,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "accepted",
                 "projection_distance": 0.002}],
    )


def replace_atomic() -> ScenarioSpec:
    return ScenarioSpec(
        name="replace_atomic",
        description="A fresher chunk of the same phase replaces the queued tail from its first "
                    "action on, in one swap: C1 runs until 70 ms, C2 from 70 ms, and no "
                    "displaced action of C1 ever runs.",
        events=[*_start(), chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 10)),
                observation(40, "O2"), *_tracking(100),
                chunk(60, "C2", 2, "O2", 40, first=70, actions=ramp(6, 8))],
        until=100,
        expect=[
            {"kind": "chunk", "chunk_id": "C2", "decision": "replaced", "displaced": 5,
             "projection_distance": 0.0},
            {"kind": "tick", "t": 68, "sent.chunk_id": "C1", "sent.index": 4},
            {"kind": "tick", "t": 70, "sent.chunk_id": "C2", "sent.index": 0},
        ],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1", "t_min": 70}],
    )


def replace_with_older_observation() -> ScenarioSpec:
    return ScenarioSpec(
        name="replace_with_older_observation",
        description="A chunk with a newer sequence but conditioned on an older observation "
                    "than the queued one may not replace it: REORDERED.",
        events=[*_start(), observation(10, "O2"),
                chunk(25, "C2", 2, "O2", 10, first=30, actions=ramp(3, 8)), *_tracking(60),
                chunk(40, "C3", 3, "O1", 0, first=50, actions=ramp(4, 6))],
        until=60,
        expect=[{"kind": "chunk", "chunk_id": "C3", "decision": "rejected",
                 "reasons": ["REORDERED"]}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C3"}],
    )


def append_after_tail() -> ScenarioSpec:
    return ScenarioSpec(
        name="append_after_tail",
        description="An 'append' chunk keeps everything queued and adds only its actions due "
                    "after the queue's end, projected from the last queued action.",
        events=[*_start(), chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 10)),
                observation(40, "O2"), *_tracking(150),
                chunk(60, "C2", 2, "O2", 40, first=70, actions=ramp(6, 8),
                      replacement_policy="append")],
        until=150,
        expect=[
            {"kind": "chunk", "chunk_id": "C2", "decision": "accepted", "merge": "append"},
            {"kind": "tick", "t": 110, "sent.chunk_id": "C1", "sent.index": 9},
            {"kind": "tick", "t": 120, "sent.chunk_id": "C2", "sent.index": 5},
        ],
        forbid=[{"kind": "tick", "sent.chunk_id": "C2", "sent.index": 4}],
    )


def blend_free_space() -> ScenarioSpec:
    shifted = [[q[0] + 0.002, *q[1:]] for q in ramp(6, 8)]
    return ScenarioSpec(
        name="blend_free_space",
        description="FREE_SPACE allows blending: the overlap cross-fades from the queued "
                    "actions to the new ones, and the blend is projected again.",
        phase="FREE_SPACE",
        events=[*_start(), chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 10),
                                 task_phase="FREE_SPACE"),
                observation(40, "O2"), *_tracking(100),
                chunk(60, "C2", 2, "O2", 40, first=70, actions=shifted, task_phase="FREE_SPACE",
                      replacement_policy="blend")],
        until=100,
        expect=[{"kind": "chunk", "chunk_id": "C2", "decision": "blended", "merge": "blend"},
                {"kind": "tick", "t": 70, "sent.chunk_id": "C2", "sent.index": 0}],
    )


def blend_not_allowed_replaces() -> ScenarioSpec:
    return ScenarioSpec(
        name="blend_not_allowed_replaces",
        description="PRE_CONTACT does not allow blending: a 'blend' request is treated as an "
                    "atomic replacement instead (never an unchecked average).",
        events=[*_start(), chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 10)),
                observation(40, "O2"), *_tracking(100),
                chunk(60, "C2", 2, "O2", 40, first=70, actions=ramp(6, 8),
                      replacement_policy="blend")],
        until=100,
        expect=[{"kind": "chunk", "chunk_id": "C2", "decision": "replaced", "merge": "replace"}],
        forbid=[{"kind": "chunk", "decision": "blended"}],
    )


def underrun_hold_escalates() -> ScenarioSpec:
    return ScenarioSpec(
        name="underrun_hold_escalates",
        description="The queue runs dry: the robot holds at the measured state (a validated "
                    "hold, never the last action repeated); after the phase's max underrun "
                    "(120 ms) the hold escalates to SAFE_HOLD.",
        events=[*_start(), chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 4)),
                *_tracking(60)],
        until=200,
        expect=[
            {"kind": "tick", "t": 60, "command": "hold", "owner": "fallback", "sent": None,
             "reason": "UNDERRUN", "mode": "RUNNING"},
            {"kind": "transition", "machine": "fallback", "from": "RUNNING", "to": "SAFE_HOLD",
             "trigger": "UNDERRUN", "t": 180},
        ],
        forbid=[{"kind": "tick", "t_min": 60, "command": "setpoint"},
                {"kind": "transition", "machine": "fallback", "t_max": 178}],
    )


SCENARIOS = [state_diverged_safe_hold, infeasible_replan_or_retreat, projected_within_bound,
             replace_atomic, replace_with_older_observation, append_after_tail,
             blend_free_space, blend_not_allowed_replaces, underrun_hold_escalates]
