"""Consecutive setpoints stay inside the limits across chunk boundaries.

Found by the core state machine: a handshake accepted in RUNNING purges the queue (new epoch)
under a moving arm; the next chunk used to be projected from the measured state at rest, and the
setpoints sent before and after the purge broke the acceleration limit.

Also found by it: a queued row that no tick sends (the next chunk replaces the queue from an
instant before the next tick) was the row that next chunk was projected from. A chunk now
follows the row the last tick before it will actually send (assurance/merge.py).
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np

from kernel.core.events import HandshakeEvent, ObservationEvent, StateEvent
from kernel.core.lines import ChunkLine
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
from tools.scenarios.base import offer

MS = 1_000_000


def _sent_until(core: Core, start_ms: int, end_ms: int, sent: dict[object, np.ndarray]) -> None:
    """Each action sent, once (an action stays in force for several ticks)."""
    for t_ms in range(start_ms, end_ms + 1, PERIOD_MS):
        command, _ = tick(core, t_ms * MS)
        if command.sent is not None:
            sent.setdefault(command.sent, np.asarray(command.target).copy())


def test_the_setpoints_sent_across_a_new_epoch_stay_inside_the_acceleration_limit() -> None:
    config = core_config("FREE_SPACE")
    core = Core(config)
    q0 = config.initial_q[:6]
    feed(core, ObservationEvent(t=0, observation_id="O1"))
    moving = q0 + np.arange(1, 3)[:, None] * 0.004  # 0.4 rad/s on every joint
    feed(core, chunk_event(0, chunk_fields("C1", 1, 0, "FREE_SPACE", "O1", 0, 0, moving)))
    sent: dict[object, np.ndarray] = {}
    _sent_until(core, 0, 10, sent)
    feed(core, HandshakeEvent(t=11 * MS, offer=offer(queue_epoch=core.status().epoch)))
    assert core.status().epoch == 1 and not core.inspect_state().queue.pending_rows(11 * MS)
    last = list(sent.values())[-1]
    stopping = np.repeat(last[None, :], 2, axis=0)  # the policy now says: stay here
    lines = feed(core, chunk_event(11, chunk_fields("C2", 2, 1, "FREE_SPACE", "O1", 0, 11,
                                                    stopping)))
    assert lines[0].decision == "accepted", lines[0]
    _sent_until(core, 12, 40, sent)
    limits, dt = config.limits, DT_MS / 1000
    arm = limits.arm_mask
    points = list(sent.values())
    assert len(points) == 4  # C1's two actions, then C2's
    for before, now, after in zip(points, points[1:], points[2:], strict=False):
        change = np.abs(after - 2 * now + before)[arm]
        assert np.all(change <= limits.acceleration[arm] * dt * dt + 1e-7), change


def test_setpoints_stay_inside_the_velocity_limit_when_a_queued_row_is_never_sent() -> None:
    """Three chunks, each within every limit on its own: A cruises at 0.02 rad per action
    (2 rad/s, under 3.14); B continues it from A's row due at 70 ms, with its first row due at
    70.5 ms; C continues from B's first row and replaces the queue from 72 ms, 1 ms after B
    arrived. No tick falls in B's first row's window, so that row is never sent: C must be
    judged against the row the tick at 70 ms sent, not against B's (found by the core state
    machine: C used to be admitted unchanged and the setpoints sent jumped 1.27x the velocity
    limit)."""
    config = core_config("FREE_SPACE")
    core = Core(config)
    q0, step = config.initial_q[:6], 0.02
    a = q0 + np.cumsum(np.minimum(0.004 * np.arange(1, 13), step))[:, None]  # ramp up, cruise
    feed(core, ObservationEvent(t=0, observation_id="O1"))
    decisions = [feed(core, chunk_event(0, chunk_fields("A", 1, 0, "FREE_SPACE", "O1", 0, 0, a)))]
    sent: dict[object, np.ndarray] = {}
    _sent_until(core, 0, 70, sent)
    feed(core, StateEvent(t=70 * MS, q=tuple(list(sent.values())[-1].tolist())))
    feed(core, ObservationEvent(t=70 * MS, observation_id="O2"))
    b = a[7] + step * np.arange(1, 5)[:, None]
    decisions.append(feed(core, chunk_event(70.5, chunk_fields("B", 2, 0, "FREE_SPACE", "O2", 70,
                                                               70.5, b))))
    c = b[0] + step * np.arange(1, 5)[:, None]
    decisions.append(feed(core, chunk_event(71, chunk_fields("C", 3, 0, "FREE_SPACE", "O2", 70,
                                                             72, c))))
    a_line, b_line, c_line = (next(x for x in lines if isinstance(x, ChunkLine))
                              for lines in decisions)
    assert a_line.projection_distance == b_line.projection_distance == 0.0
    assert c_line.decision == "rejected" or c_line.projection_distance > 0.0, c_line
    _sent_until(core, 72, 100, sent)
    points = list(sent.values())
    v_step = config.limits.velocity[:6] * DT_MS / 1000
    for before, now in pairwise(points):
        assert np.all(np.abs(now - before) <= v_step + 1e-9), (now - before)
