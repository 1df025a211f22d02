"""Real-time chunking across the network: the committed prefix an observation carries, and the
gate a chunk conditioned on it must pass.

A policy infers while the arm keeps moving. With real-time chunking (RTC) the robot tells the
policy what it has committed to and will execute meanwhile: the *prefix*, the queued actions
in force from the observation's time on, on the policy's action grid, and the *delay*, how
many of them the inference is expected to take (from the measured round trip). The policy
returns a chunk on the prefix's grid whose first ``delay`` actions reproduce the prefix, so
wherever inside that stretch the new chunk takes over, its seam is the motion already
commanded, not a jump to a plan made without it.

warden knows exactly which actions it committed, so it checks what a remote policy claims
(:func:`rtc_reasons`): a chunk that says it was conditioned (``rtc_delay``) must start where
the prefix it was sent starts, on the same grid, and agree with the prefix over its
first ``rtc_delay`` actions within the phase's ``max_projection`` (RTC_PREFIX_MISMATCH); and no
more of its actions may be due when it arrives than that delay (RTC_DELAY_EXCEEDED), since
those would be actions planned without knowing what ran meanwhile. A chunk that passes may drop
those first actions even where the phase forbids trimming: they are the committed prefix,
which is running, not the policy's own plan (:func:`assurance.gates.time_verdict`).

Pure: no I/O, no clock.
"""

from __future__ import annotations

from typing import Annotated

import msgspec
import numpy as np

from assurance.envelope import Chunk
from assurance.limits import JointLimits
from assurance.queue import ActionQueue
from assurance.reasons import ReasonCode as R

MAX_PREFIX_ROWS = 1024
"""The most committed actions one observation carries (and the largest ``rtc_delay``)."""
PrefixLength = Annotated[int, msgspec.Meta(ge=0, le=MAX_PREFIX_ROWS)]


class RtcPrefix(msgspec.Struct, frozen=True, kw_only=True):
    """What an observation told the policy for real-time chunking: ``actions[k]`` is the
    committed action due at ``first_due + k * action_dt`` (the policy's action space: every
    dimension the session's chunks carry), from the one in force at the observation's time on;
    ``delay`` the actions the inference is expected to take, ``horizon`` the actions the robot
    expects to execute of the answer before a later one replaces them."""

    actions: tuple[tuple[float, ...], ...]
    first_due: int
    """Client ns: when the first of them was due (at or before the observation)."""
    action_dt: Annotated[int, msgspec.Meta(gt=0)]
    delay: PrefixLength
    horizon: PrefixLength


class Committed(msgspec.Struct, frozen=True, eq=False):
    """The queued actions from the one in force at some instant on: ``rows[k]`` is due at
    ``first_due + k * action_dt``."""

    first_due: int
    rows: np.ndarray


def committed_prefix(queue: ActionQueue, t: int, action_dt: int,
                     limit: int = MAX_PREFIX_ROWS) -> Committed:
    """The queued actions from the one in force at ``t`` on, one per ``action_dt`` for as long
    as the queue has one (at most ``limit``; none: nothing is committed). The grid starts at
    the due time of the action in force, so on the chunks' own grid the rows are the queued
    actions themselves, not samples of them taken between their due times."""
    row = queue.row_in_force(t)
    start = t if row is None else row.due
    rows: list[np.ndarray] = []
    while len(rows) < limit:
        value = queue.value_at(start + len(rows) * action_dt)
        if value is None:
            break
        rows.append(value)
    return Committed(start, np.array(rows, dtype=float) if rows else np.zeros((0, 0)))


def rtc_reasons(chunk: Chunk, prefix: RtcPrefix | None, t_obs: int | None,
                first_due: int | None, late: int, bound: float, limits: JointLimits,
                changed: bool = False) -> tuple[list[R], str | None]:
    """The RTC gate (module docstring) for a chunk that says it was conditioned on a prefix
    (``rtc_delay``); none for one that does not. ``late``: its actions already due when it
    arrived; ``bound``: the phase's ``max_projection`` (rad) for the arm's joints (a gripper's
    opening must agree within its event threshold: a gripper event among the actions dropped
    would be lost); ``changed``: an admission or a purge changed the queue since the prefix was
    taken, so it is not what runs now. Returns the reasons and what was wrong."""
    delay = chunk.rtc_delay
    if delay is None:
        return [], None
    problem = _prefix_problem(chunk, delay, prefix, t_obs, first_due, bound, limits)
    if problem is None and changed:
        problem = "the queue changed after its observation: the prefix is not what runs now"
    if problem is not None:
        return [R.RTC_PREFIX_MISMATCH], problem
    if late > delay:
        return [R.RTC_DELAY_EXCEEDED], (f"{late} of its actions were due when it arrived, "
                                        f"conditioned on a delay of {delay}")
    return [], None


def _prefix_problem(chunk: Chunk, delay: int, prefix: RtcPrefix | None, t_obs: int | None,
                    first_due: int | None, bound: float, limits: JointLimits) -> str | None:
    if prefix is None or t_obs is None:
        return f"observation {chunk.observation_id!r} carried no committed prefix"
    dt = chunk.time("action_dt")
    if dt != prefix.action_dt:
        return f"action_dt {dt} ns, the prefix's grid is {prefix.action_dt} ns"
    if first_due is None or 2 * abs(first_due - prefix.first_due) >= prefix.action_dt:
        return "its first action is not due when the prefix's first action was"
    if delay > len(prefix.actions) or delay > chunk.horizon:
        return (f"conditioned on {delay} actions; the prefix had {len(prefix.actions)}, the "
                f"chunk {chunk.horizon}")
    if delay == 0:
        return None
    committed = np.array(prefix.actions[:delay], dtype=float)
    if not committed.shape[1] == chunk.actions.shape[1] == limits.dim:
        return (f"the prefix has {committed.shape[1]} values per action, the chunk "
                f"{chunk.actions.shape[1]}")
    gap = np.abs(chunk.actions[:delay] - committed)
    arm = float(gap[:, limits.arm_mask].max())
    if not arm <= bound:  # NaN is not within any bound
        return f"its first {delay} actions are {arm:.4g} rad from the prefix (bound {bound:g})"
    grip = limits.gripper_index
    if grip is not None and not float(gap[:, grip].max()) <= limits.gripper_event_threshold:
        return f"its gripper differs from the prefix's within its first {delay} actions"
    return None
