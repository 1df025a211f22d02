"""The core reports its decisions to the shell as typed records, with the lines that log them:
every chunk line has its :class:`ChunkDecision` in the same step (the ``computed`` event's step
for a chunk decided in a job), every handshake line its :class:`HandshakeDecision`, in order."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest

from assurance.handshake import (
    HandshakeDecision,
    HandshakeOffer,
    MalformedOffer,
    evaluate,
    offer_in,
)
from assurance.reasons import ReasonCode
from kernel.core.effects import ChunkDecision, Compute, DecisionRecord, Step
from kernel.core.events import ComputedEvent, Event, HandshakeEvent
from kernel.core.jobs import run_job
from kernel.core.lines import ChunkLine, HandshakeLine, Line
from kernel.core.runtime import Core
from kernel.journal import event_record
from kernel.scenario.load import load_scenario
from tests.core.test_handshake import ALLOW, HELLO, OFFER

SCENARIOS = sorted((Path(__file__).resolve().parents[2] / "manifests" / "scenarios")
                   .glob("*.json"))


def _steps(core: Core, event: Event) -> Iterator[tuple[Event, Step]]:
    """The event's step, then the steps of the jobs it asked for, run inline."""
    step = core.step(event)
    yield event, step
    for effect in step.effects:
        if isinstance(effect, Compute):
            result = run_job(effect.job, core.config.limits, core.config.cartesian)
            yield from _steps(core, ComputedEvent(t=event.t, result=result))


def _expected(lines: tuple[Line, ...]) -> list[DecisionRecord]:
    records: list[DecisionRecord] = []
    for line in lines:
        if isinstance(line, ChunkLine):
            records.append(ChunkDecision(chunk_id=line.chunk_id, decision=line.decision,
                                         reasons=line.reasons))
        elif isinstance(line, HandshakeLine):
            records.append(HandshakeDecision(decision=line.decision,
                                             fingerprint=line.fingerprint,
                                             reasons=line.reasons, protocol=line.protocol))
    return records


@pytest.mark.parametrize("path", SCENARIOS, ids=[p.stem for p in SCENARIOS])
def test_every_logged_decision_comes_with_its_typed_record(path: Path) -> None:
    scenario = load_scenario(path)
    core = Core(scenario.config)
    decided_in_jobs = 0
    for item in scenario.timeline():
        for event, step in _steps(core, item):
            assert list(step.decisions) == _expected(step.lines), event
            decided_in_jobs += isinstance(event, ComputedEvent) and bool(step.decisions)
    if path.stem.startswith("cartesian_"):
        assert decided_in_jobs > 0  # the case the shell used to miss: decided in a job


def test_an_offer_is_journaled_as_it_came_typed_or_malformed() -> None:
    typed = offer_in(OFFER)
    assert isinstance(typed, HandshakeOffer)
    record = event_record(HandshakeEvent(t=1, offer=typed))
    assert record["offer"] == msgspec.to_builtins(msgspec.convert(OFFER, HandshakeOffer))
    raw = {**OFFER, "action_dim": "seven"}
    malformed = offer_in(raw)
    assert isinstance(malformed, MalformedOffer) and "action_dim" in malformed.detail
    assert event_record(HandshakeEvent(t=1, offer=malformed))["offer"] == raw
    decision, session = evaluate(HELLO, malformed, ALLOW)
    assert decision.reasons == (ReasonCode.MALFORMED,) and session is None
