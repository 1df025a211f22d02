"""Scenarios for real-time chunking across the network (assurance/rtc.py): an observation
carries the committed prefix, and a chunk that says it was conditioned on it is checked
against it. PRE_CONTACT forbids trimming: only the committed prefix may be dropped there."""

from __future__ import annotations

from typing import Any

from tools.scenarios.base import Q0, ScenarioSpec, chunk, observation, ramp
from tools.scenarios.base import state as st

DT_NS = 10_000_000
"""The action grid of every chunk here (10 ms)."""
PREFIX_AT_40 = ramp(3, 8)
"""C1's actions due at 40, 50, ... 110 ms: what was committed when O2 was taken at 40 ms."""


def _start(phase: str = "PRE_CONTACT") -> list[dict[str, Any]]:
    """C1 (actions 1..10 of the approach, due from 20 ms) runs, the arm following it; O2 is
    taken at 40 ms with the committed prefix (2 actions of delay, 4 of execution horizon)."""
    o2 = observation(40, "O2")
    o2["rtc"] = {"actions": PREFIX_AT_40, "first_action_time_ns": 40 * 1_000_000,
                 "action_dt_ns": DT_NS, "delay": 2, "horizon": 4}
    following = [st(20 + 10 * k, q) for k, q in enumerate(ramp(1, 7))]
    events = [st(0, list(Q0)), observation(0, "O1"),
              chunk(20, "C1", 1, "O1", 0, first=20, actions=ramp(1, 10), task_phase=phase),
              o2, *following]
    return sorted(events, key=lambda e: e["t"])


def _conditioned(t: float, actions: list[list[float]], phase: str = "PRE_CONTACT",
                 ) -> dict[str, Any]:
    return chunk(t, "C2", 2, "O2", 40, first=40, actions=actions, rtc_delay=2, task_phase=phase)


def rtc_prefix_honoured() -> ScenarioSpec:
    return ScenarioSpec(
        name="rtc_prefix_honoured",
        description="O2 carried the committed prefix (C1's actions from 40 ms on) and a delay "
                    "of 2 actions. C2 answers it starting at the observation's time, its first "
                    "2 actions the prefix itself, and arrives at 55 ms with those 2 due: they "
                    "are dropped although PRE_CONTACT forbids trimming (they are the committed "
                    "motion, already running), and C2 takes over at 60 ms on the same path.",
        events=[*_start(), _conditioned(55, ramp(3, 10))],
        until=80,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "accepted"},
                {"kind": "chunk", "chunk_id": "C2", "decision": "trimmed", "t": 55},
                {"kind": "tick", "t": 60, "sent.chunk_id": "C2", "sent.index": 2}],
        forbid=[{"kind": "chunk", "chunk_id": "C2", "decision": "rejected"}],
    )


def rtc_prefix_mismatch() -> ScenarioSpec:
    off = [v + (0.05 if j == 1 else 0.0) for j, v in enumerate(ramp(3, 1)[0])]
    return ScenarioSpec(
        name="rtc_prefix_mismatch",
        description="C2 says it was conditioned on O2's prefix, but its first action is 0.05 "
                    "rad from it on the shoulder (the phase's max_projection is 0.01): it was "
                    "not planned from the committed motion. RTC_PREFIX_MISMATCH; C1 keeps "
                    "running.",
        events=[*_start(), _conditioned(55, [off, *ramp(4, 9)])],
        until=80,
        expect=[{"kind": "chunk", "chunk_id": "C2", "decision": "rejected",
                 "reasons": ["RTC_PREFIX_MISMATCH"]},
                {"kind": "tick", "t": 60, "sent.chunk_id": "C1"}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C2"}],
    )


def rtc_delay_exceeded() -> ScenarioSpec:
    return ScenarioSpec(
        name="rtc_delay_exceeded",
        description="In FREE_SPACE, which allows trimming: C2 honours O2's prefix but "
                    "arrives at 75 ms, when 4 of its actions are due and it was conditioned on "
                    "a delay of 2. Trimming would run actions the policy planned without "
                    "knowing what ran meanwhile: RTC_DELAY_EXCEEDED. The refused chunk answered "
                    "the request in flight, so the next request goes out at the next tick, not "
                    "after request_retry_ms.",
        phase="FREE_SPACE",
        events=[*_start("FREE_SPACE"), _conditioned(75, ramp(3, 10), "FREE_SPACE")],
        until=90,
        expect=[{"kind": "chunk", "chunk_id": "C2", "decision": "rejected",
                 "reasons": ["RTC_DELAY_EXCEEDED"]},
                {"kind": "request", "t": 76, "observation_id": "O2"},
                {"kind": "tick", "t": 80, "sent.chunk_id": "C1"}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C2"}],
    )


def rtc_without_a_prefix() -> ScenarioSpec:
    events = [{k: v for k, v in e.items() if k != "rtc"} for e in _start()]
    return ScenarioSpec(
        name="rtc_without_a_prefix",
        description="O2 carried no prefix (the server did not offer real-time chunking), yet "
                    "C2 says it was conditioned on one: RTC_PREFIX_MISMATCH, whatever its "
                    "actions.",
        events=[*events, _conditioned(55, ramp(3, 10))],
        until=80,
        expect=[{"kind": "chunk", "chunk_id": "C2", "decision": "rejected",
                 "reasons": ["RTC_PREFIX_MISMATCH"]}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C2"}],
    )


SCENARIOS = (rtc_prefix_honoured, rtc_prefix_mismatch, rtc_delay_exceeded, rtc_without_a_prefix)
