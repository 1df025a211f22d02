"""What warden's link tells a server that offered real-time chunking (assurance/rtc.py), and
from what: the committed actions on the server's action grid, the inference delay from the
round trips measured on this connection, and the execution horizon.

Sans-I/O, like the protocol that owns it: times are passed in.

- The grid is the ``action_dt`` of the last chunk the server sent on this connection: before
  the first one, warden does not know it, and sends no prefix.
- The delay is the 95th percentile of the last :data:`WINDOW` round trips (observation sent
  to its answer taken for admission; the longest of them while there are fewer than
  :data:`FEW`), plus how long before the observation the first committed action was due, in
  actions, rounded up: the actions of the answer that will be due, in 19 cases out of 20, when
  it is admitted. Before the first round trip: no prefix.
- The horizon is the chunk horizon the server offered, less that delay (at most 1024): the
  actions of its answer after the seam, which warden will run unless a later answer takes
  over first.
"""

from __future__ import annotations

import math
from collections import deque

from assurance.rtc import MAX_PREFIX_ROWS, Committed, RtcPrefix

WINDOW = 50
"""Round trips the delay is estimated from (the most recent ones)."""
FEW = 20
"""Fewer round trips than this: the delay is planned for the longest of them."""


class PrefixPlanner:
    """The prefix one connection sends (module docstring)."""

    def __init__(self) -> None:
        self.offered = False
        self.chunk_horizon = 0
        self._grid_ns: int | None = None
        self._round_trips: deque[int] = deque(maxlen=WINDOW)

    def begin(self, offered: bool, chunk_horizon: int) -> None:
        """A new connection's offer: what this server does, nothing measured yet."""
        self.offered, self.chunk_horizon = offered, chunk_horizon
        self._grid_ns = None
        self._round_trips.clear()

    def answered(self, round_trip_ns: int, action_dt_ns: int | None) -> None:
        """A chunk answered an observation sent ``round_trip_ns`` ago, on that grid."""
        self._round_trips.append(max(0, round_trip_ns))
        if action_dt_ns is not None and action_dt_ns > 0:
            self._grid_ns = action_dt_ns

    def _round_trip(self) -> int:
        """The round trip to plan for: the 95th percentile once there are enough to tell
        one, the longest seen before (a connection's first answers are few, and a delay
        too short refuses the answer)."""
        ordered = sorted(self._round_trips)
        if len(ordered) < FEW:
            return ordered[-1]
        return ordered[math.ceil(0.95 * len(ordered)) - 1]

    def grid_ns(self) -> int | None:
        """The grid to capture the committed actions on, or None: no prefix to send."""
        if not self.offered or not self._round_trips:
            return None
        return self._grid_ns

    def prefix(self, committed: Committed | None, now_ns: int) -> RtcPrefix | None:
        """The prefix for the committed actions captured on :meth:`grid_ns`'s grid at
        ``now_ns`` (None when nothing is committed, or none was asked for). The delay counts
        from the first of them, which was due up to one step before now."""
        grid = self.grid_ns()
        if grid is None or committed is None or committed.rows.shape[0] == 0:
            return None
        rows = committed.rows[:MAX_PREFIX_ROWS]
        since = max(0, now_ns - committed.first_due)
        delay = min(rows.shape[0], math.ceil((self._round_trip() + since) / grid))
        return RtcPrefix(actions=tuple(tuple(row) for row in rows.tolist()),
                         first_due=committed.first_due, action_dt=grid, delay=delay,
                         horizon=min(MAX_PREFIX_ROWS, max(0, self.chunk_horizon - delay)))
