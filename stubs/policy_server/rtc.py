"""Real-time chunking on the reference server's side: an answer that continues the committed
prefix an observation carries (docs/protocol.md, "Real-time chunking")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from peer.protocol import INT64_MAX, Prefix, ProtocolViolation, payload_rows
from stubs.policy_server.config import ServerConfig
from stubs.policy_server.policy import InsertionPolicy

MAX_PREFIX_ROWS = 1024


@dataclass(frozen=True, slots=True)
class ServerPrefix:
    """A prefix as this server reads it: the rows, their first due time in its own clock, the
    grid and the delay."""

    rows: np.ndarray
    first_due: int
    action_dt: int
    delay: int


def read_prefix(cfg: ServerConfig, prefix: Prefix | None,
                client_offset: int | None) -> ServerPrefix | None:
    """The observation's prefix, checked when it arrives (a bad one ends the connection with a
    protocol violation, before any inference); None when this server does not condition on it:
    not offered, none sent, another grid, or no clock report from the client yet (the prefix's
    times are the client's).

    Raises:
        ProtocolViolation: its actions are not rows of the policy's width, or its first due
            time cannot be this server's.
    """
    if not cfg.rtc or prefix is None or client_offset is None:
        return None
    rows = payload_rows(prefix.actions, len(cfg.goal), MAX_PREFIX_ROWS)
    if prefix.action_dt != round(cfg.action_dt_ms * 1e6):
        return None
    first_due = prefix.first_action_time - client_offset
    if not -INT64_MAX <= first_due <= INT64_MAX:
        raise ProtocolViolation("the prefix's first_action_time is out of this clock's range")
    return ServerPrefix(rows, first_due, prefix.action_dt, prefix.delay)


def conditioned_actions(cfg: ServerConfig, policy: InsertionPolicy, rng: np.random.Generator,
                        committed: ServerPrefix, qd: np.ndarray | None,
                        ) -> tuple[np.ndarray, int, int] | None:
    """The prefix's first ``delay`` actions, then the policy's plan from the last of them (at
    the velocity the prefix ends with), the whole due from the prefix's first action on; the
    delay; and that first due time. None (answer as without it) for a delay of 0."""
    rows = committed.rows
    delay = min(committed.delay, rows.shape[0], cfg.horizon)
    if delay == 0:
        return None
    dt_s = committed.action_dt / 1e9
    start = rows[delay - 1]
    velocity = (rows[delay - 1] - rows[delay - 2]) / dt_s if delay >= 2 else qd
    plan = policy.actions(start, dt_s, rng, velocity)
    return np.vstack((rows[:delay], plan[: cfg.horizon - delay])), delay, committed.first_due
