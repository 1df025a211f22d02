"""The setpoint a chunk continues is only ever one the policy's last tick sent.

A tick the policy does not own (here an underrun: the queue ran dry) sends the hold, so the
next chunk must start from that hold at rest; a stale "last setpoint" left from an earlier
policy tick would have it continue a motion the arm is no longer making (issue 15, item 14).
"""

from __future__ import annotations

import numpy as np

from kernel.core.events import ObservationEvent
from kernel.core.lines import ChunkLine
from kernel.core.runtime import Core
from tests.runtime.machine_setup import chunk_event, chunk_fields, core_config, feed, tick

MS = 1_000_000


def test_a_tick_the_policy_does_not_own_clears_the_last_setpoint() -> None:
    config = core_config("FREE_SPACE")
    core = Core(config)
    q0 = config.initial_q[:6]
    feed(core, ObservationEvent(t=0, observation_id="O1"))
    moving = q0 + np.arange(1, 3)[:, None] * 0.004  # two 10 ms rows, 0.4 rad/s
    feed(core, chunk_event(0, chunk_fields("C1", 1, 0, "FREE_SPACE", "O1", 0, 0, moving)))
    for t_ms in range(0, 20, 2):
        sent, _ = tick(core, t_ms * MS)
        assert sent.sent is not None and core.inspect_state().last_setpoint is not None
    dry, _ = tick(core, 20 * MS)  # the last row's window has passed: the fallback holds
    assert dry.sent is None and dry.reason == "UNDERRUN"
    assert core.inspect_state().last_setpoint is None
    hold = core.inspect_state().hold_q
    assert hold is not None
    feed(core, ObservationEvent(t=20 * MS, observation_id="O2"))
    stay = np.repeat(moving[-1][None, :], 3, axis=0)
    lines = feed(core, chunk_event(20, chunk_fields("C2", 2, 0, "FREE_SPACE", "O2", 20, 20,
                                                    stay)))
    line = next(x for x in lines if isinstance(x, ChunkLine))
    assert line.decision == "accepted", line
    segment = core.inspect_state().queue.segments[-1]
    assert segment.chunk_id == "C2"
    np.testing.assert_array_equal(segment.ref_q, hold)  # from the hold, at rest
