"""A chunk admitted right after a new epoch continues the motion the last tick sent.

Found by the core state machine: a handshake accepted in RUNNING purges the queue (new epoch)
under a moving arm; the next chunk used to be projected from the measured state at rest, and the
setpoints sent before and after the purge broke the acceleration limit.
"""

from __future__ import annotations

import numpy as np

from kernel.core.events import HandshakeEvent, ObservationEvent
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
    feed(core, HandshakeEvent(t=11 * MS, offer=offer(queue_epoch=core.state.epoch)))
    assert core.state.epoch == 1 and not core.state.queue.pending_rows(11 * MS)
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
