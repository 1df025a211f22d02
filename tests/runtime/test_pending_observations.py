"""A chunk answers a pending observation or nothing: driven through ``Core.step`` only."""

from __future__ import annotations

import numpy as np

from assurance.fallback import Mode
from assurance.reasons import ReasonCode as R
from kernel.core.events import ObservationEvent
from kernel.core.lines import ChunkLine
from kernel.core.runtime import Core
from tests.runtime.machine_setup import chunk_event, chunk_fields, core_config, feed
from tools.scenarios.base import Q0

MS = 1_000_000


def _lines(core: Core, *events: object) -> list[ChunkLine]:
    out: list[ChunkLine] = []
    for event in events:
        out += [line for line in feed(core, event) if isinstance(line, ChunkLine)]  # type: ignore[arg-type]
    return out


def _chunk(t_ms: float, chunk_id: str, sequence: int, observation: str,
           first_ms: float | None = None) -> object:
    actions = np.tile(np.array(Q0), (8, 1))
    first = t_ms + 10 if first_ms is None else first_ms
    return chunk_event(t_ms, chunk_fields(chunk_id, sequence, 0, "FREE_SPACE", observation, 0,
                                          first, actions))


def test_second_answers_are_refused_at_once_and_never_degrade() -> None:
    core = Core(core_config(degrade_after=2))
    feed(core, ObservationEvent(t=0, observation_id="o1"))
    (first,) = _lines(core, _chunk(5, "c1", 1, "o1"))
    assert first.decision == "accepted"
    later = _lines(core, *(_chunk(6 + k, f"flood-{k}", 2 + k, "o1") for k in range(10)))
    assert [line.reasons for line in later] == [(R.OBSERVATION_ANSWERED,)] * 10
    assert all(line.projection_distance is None and line.divergence is None for line in later)
    assert core.status().mode is Mode.RUNNING  # ten of them, degrade_after is 2
    assert len(core.inspect_state().memory) == 1  # none of them entered the duplicate memory
    # a duplicate of the admitted answer is still a duplicate, and the next request is open
    (again,) = _lines(core, _chunk(17, "c1", 1, "o1", first_ms=15))  # c1 again, later
    assert again.decision == "ignored" and again.reasons == (R.DUPLICATE,)
    feed(core, ObservationEvent(t=20 * MS, observation_id="o2"))
    (answer,) = _lines(core, _chunk(25, "c2", 20, "o2"))
    assert answer.decision in ("accepted", "replaced")


def test_a_refused_answer_leaves_its_observation_pending() -> None:
    core = Core(core_config())
    feed(core, ObservationEvent(t=0, observation_id="o1"))
    stale = chunk_fields("c1", 1, 0, "FREE_SPACE", "o1", 0, 15, np.tile(np.array(Q0), (8, 1)),
                         inference_start=500)
    (refused,) = _lines(core, chunk_event(5, stale))
    assert refused.decision == "rejected" and R.OBSERVATION_ANSWERED not in refused.reasons
    (answer,) = _lines(core, _chunk(6, "c2", 2, "o1"))
    assert answer.decision == "accepted"
