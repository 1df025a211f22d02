"""The end-of-run summary: what the decision log and the shell's counters say about a run.

Built from the same decision-log lines a replay prints, plus the figures only a live run has
(cycle verdicts, loop lateness, inference round trips). ``as_dict()`` is what ``--json``
writes; ``render()`` is the table ``warden run`` prints.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass, field
from typing import Any

from kernel.core.lines import (
    ADMITTED,
    ChunkLine,
    Decision,
    Line,
    Machine,
    RequestLine,
    TickLine,
    TransitionLine,
)

__all__ = ["ADMITTED", "CycleResult", "RunSummary", "percentiles"]


def percentiles(values: list[float]) -> dict[str, float | None]:
    """p50 / p95 / max of ``values`` (None when there are none)."""
    if not values:
        return {"p50": None, "p95": None, "max": None, "n": 0}
    ordered = sorted(values)
    pick = lambda p: ordered[min(len(ordered) - 1, int(p * len(ordered)))]  # noqa: E731
    return {"p50": pick(0.50), "p95": pick(0.95), "max": ordered[-1], "n": len(ordered)}


@dataclass
class CycleResult:
    index: int
    verified: bool
    depth_m: float | None
    """None: the cycle ended before anything was measured (the run was cut short)."""
    duration_s: float
    reason: str = ""


@dataclass
class RunSummary:
    """Accumulates decision-log lines as they are produced."""

    proposals: Counter[str] = field(default_factory=Counter)
    refusals: defaultdict[str, Counter[str]] = field(default_factory=lambda: defaultdict(Counter))
    decisions: Counter[str] = field(default_factory=Counter)
    projection: list[float] = field(default_factory=list)
    action_age_ms: list[float] = field(default_factory=list)
    round_trip_ms: list[float] = field(default_factory=list)
    queue_depth: list[float] = field(default_factory=list)
    transitions: list[dict[str, Any]] = field(default_factory=list)
    requests: int = 0
    ticks: int = 0
    cycles: list[CycleResult] = field(default_factory=list)
    loop: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    _phase: str = "IDLE"
    _pending: list[dict[str, Any]] = field(default_factory=list)

    def observe_all(self, lines: tuple[Line, ...] | list[Line]) -> None:
        for line in lines:
            self.observe(line)

    def observe(self, line: Line) -> None:
        if isinstance(line, TickLine):
            self._tick(line)
        elif isinstance(line, ChunkLine):
            self._chunk(line)
        elif isinstance(line, TransitionLine):
            self._transition(line)
        elif isinstance(line, RequestLine):
            self.requests += 1

    def _tick(self, line: TickLine) -> None:
        self.ticks += 1
        self._phase = line.phase
        if line.age_ms is not None and line.sent is not None:
            self.action_age_ms.append(float(line.age_ms))
        for pending in self._pending:
            if line.mode == pending["to"]:
                pending["latency_ms"] = round(float(line.t) - pending["t"], 6)
        self._pending = [p for p in self._pending if "latency_ms" not in p]

    def _chunk(self, line: ChunkLine) -> None:
        self.proposals[self._phase] += 1
        self.decisions[line.decision] += 1
        self.queue_depth.append(float(line.queue_depth))
        if line.decision in ADMITTED:
            if line.projection_distance is not None:
                self.projection.append(line.projection_distance)
            if line.observation_age_ms is not None:
                self.round_trip_ms.append(float(line.observation_age_ms))
        elif line.decision == Decision.REJECTED:
            for reason in line.reasons:
                self.refusals[self._phase][reason] += 1

    def _transition(self, line: TransitionLine) -> None:
        if line.machine == Machine.TASK and line.accepted:
            self._phase = line.to
        if line.machine != Machine.FALLBACK or not line.accepted:
            return
        record = {"t": float(line.t), "from": line.from_, "to": line.to,
                  "trigger": line.trigger}
        self.transitions.append(record)
        self._pending.append(record)

    def as_dict(self) -> dict[str, Any]:
        return {
            "cycles": {"attempted": len(self.cycles),
                       "verified": sum(c.verified for c in self.cycles),
                       "detail": [c.__dict__ for c in self.cycles]},
            "proposals_by_phase": dict(self.proposals),
            "decisions": dict(self.decisions),
            "refusals_by_phase_and_reason": {p: dict(c) for p, c in self.refusals.items()},
            "projection_distance_rad": percentiles(self.projection),
            "action_age_ms": percentiles(self.action_age_ms),
            "inference_round_trip_ms": percentiles(self.round_trip_ms),
            "queue_depth_actions": percentiles(self.queue_depth),
            "fallback_transitions": self.transitions,
            "inference_requests": self.requests,
            "ticks": self.ticks,
            "loop": self.loop,
            **self.extra,
        }
