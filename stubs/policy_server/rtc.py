"""Real-time chunking on the reference server's side: an answer that continues the committed
prefix an observation carries (docs/protocol.md, "Real-time chunking")."""

from __future__ import annotations

import numpy as np

from stubs.policy_server.config import ServerConfig
from stubs.policy_server.policy import InsertionPolicy
from stubs.policy_server.protocol import Prefix, payload_rows

MAX_PREFIX_ROWS = 1024


def conditioned_actions(cfg: ServerConfig, policy: InsertionPolicy, rng: np.random.Generator,
                        prefix: Prefix | None, qd: np.ndarray | None,
                        client_offset: int) -> tuple[np.ndarray, int, int] | None:
    """When this server offers it and ``prefix`` is on its grid: the prefix's first ``delay``
    actions, then the policy's plan from the last of them (at the velocity the prefix ends
    with), the whole due from the prefix's first action on; the delay; and that first due time
    in this server's clock (``client_offset``: the client's clock report). None: answer as
    without it.

    Raises:
        ProtocolViolation: the prefix's actions are not rows of the policy's width.
    """
    if not cfg.rtc or prefix is None or prefix.action_dt != round(cfg.action_dt_ms * 1e6):
        return None
    rows = payload_rows(prefix.actions, len(cfg.goal), MAX_PREFIX_ROWS)
    delay = min(prefix.delay, rows.shape[0], cfg.horizon)
    if delay == 0:
        return None
    dt_s = prefix.action_dt / 1e9
    start = rows[delay - 1]
    velocity = (rows[delay - 1] - rows[delay - 2]) / dt_s if delay >= 2 else qd
    plan = policy.actions(start, dt_s, rng, velocity)
    first = prefix.first_action_time - client_offset
    return np.vstack((rows[:delay], plan[: cfg.horizon - delay])), delay, first
