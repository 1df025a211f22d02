"""Expiry in the running core: a long tail is admitted, runs while young, and is dropped at the
instant its rows become too old (assurance.clock.expires_at), to the nanosecond.

The core computes the instant once per chunk at admission; the tick drops the head segment once
the instant is reached. These tests pin that the tick uses exactly that rule, with and without
a foreign clock's uncertainty.
"""

from __future__ import annotations

import numpy as np
import pytest

from assurance.clock import expires_at
from kernel.core.events import ClockSyncEvent, ObservationEvent
from kernel.core.lines import ChunkLine, QueueLine
from kernel.core.runtime import Core
from tests.runtime.machine_setup import (
    DT_MS,
    PERIOD_MS,
    chunk_event,
    chunk_fields,
    core_config,
    feed,
    tick,
)

MS = 1_000_000
ROWS = 30  # 300 ms of actions on a 10 ms grid: far longer than the 200 ms age bound
MAX_AGE_MS = 200  # FREE_SPACE's bound in the standard cell


def _long_tail(core: Core, **overrides: object) -> ChunkLine:
    q0 = core.config.initial_q[:6]
    actions = q0 + np.arange(1, ROWS + 1)[:, None] * 0.0005  # slow: every bound far away
    feed(core, ObservationEvent(t=0, observation_id="O1"))
    lines = feed(core, chunk_event(0, chunk_fields("C1", 1, 0, "FREE_SPACE", "O1", 0, 0, actions,
                                                   **overrides)))
    return next(line for line in lines if isinstance(line, ChunkLine))


def _run_until(core: Core, end_ns: int) -> None:
    t = 0
    while t < end_ns:
        command, _ = tick(core, t)
        assert command.sent is not None, f"nothing sent at {t} ns"
        t += PERIOD_MS * MS


@pytest.mark.parametrize("uncertainty_ms", [0, 3])
def test_a_long_tail_runs_until_the_instant_it_is_too_old(uncertainty_ms: int) -> None:
    core = Core(core_config("FREE_SPACE", clock_uncertainty_ms=uncertainty_ms))
    decision = _long_tail(core)
    assert decision.decision == "accepted", decision  # a long tail alone refuses nothing
    expiry = expires_at(0, MAX_AGE_MS * MS, uncertainty_ms * MS)
    _run_until(core, expiry - 1)

    last_young, lines = tick(core, expiry - 1)  # age + uncertainty == bound: still runs
    assert last_young.sent is not None
    assert not [line for line in lines if isinstance(line, QueueLine)]
    index = last_young.sent.index
    assert index == (expiry - 1) // (DT_MS * MS)

    dropped, lines = tick(core, expiry)  # 1 ns later: too old
    assert dropped.sent is None and dropped.reason == "UNDERRUN"
    expire = [line for line in lines if isinstance(line, QueueLine)]
    assert len(expire) == 1 and expire[0].action == "expire"
    assert expire[0].chunk_id == "C1" and expire[0].dropped == ROWS - index
    assert expire[0].reason == "EXPIRED"


def test_a_foreign_clock_brings_the_instant_earlier_by_half_its_round_trip() -> None:
    core = Core(core_config("FREE_SPACE", clock_uncertainty_ms=1))
    offset_ms, round_trip_ms = -5000, 8
    feed(core, ClockSyncEvent(t=0, domain="server", offset=offset_ms * MS,
                              round_trip=round_trip_ms * MS))
    decision = _long_tail(core, clock_domain="server", first_action_time=-offset_ms,
                          inference_start=-offset_ms + 2)
    assert decision.decision == "accepted", decision
    expiry = expires_at(0, MAX_AGE_MS * MS, (1 + round_trip_ms // 2) * MS)
    _run_until(core, expiry - 1)
    assert tick(core, expiry - 1)[0].sent is not None
    assert tick(core, expiry)[0].sent is None
