"""Motions a policy might propose to the standard cell, from legal to far beyond its limits.

The cell's limits are read from the scenario file's robot section (``tools.scenarios.base``),
so the tests that judge what the core sends use the limits as stated, not as the core derived
them. Steps are per action on the policy's 10 ms grid.
"""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from tests.runtime.machine_setup import DT_MS
from tools.scenarios.base import Q0, robot

# The cell's limits as the scenario file states them: the oracle for every sent setpoint. The
# tight cell has the standard rates but only ±0.15 rad of travel around the start, so that
# streams of chunks reach the position limits.
STANDARD = robot()
TIGHT = {**STANDARD, "position_limits": [[q - 0.15, q + 0.15] for q in Q0]}
V_STEP = np.array(STANDARD["velocity_limits"]) * DT_MS / 1000
A_STEP = np.array(STANDARD["acceleration_limits"]) * (DT_MS / 1000) ** 2


def position_limits(doc: dict) -> tuple[np.ndarray, np.ndarray]:
    pairs = doc["position_limits"]
    return np.array([lo for lo, _ in pairs]), np.array([hi for _, hi in pairs])


@st.composite
def pushed_actions(draw: st.DrawFn, start: np.ndarray, horizon: int, moving: np.ndarray,
                   heading: np.ndarray, push: tuple[float, float], cap: float) -> np.ndarray:
    """A policy that keeps speeding up along ``heading``: each joint's step changes by
    ``push`` (a range, in units of the acceleration limit) per row, up to ``cap`` times the
    velocity limit. Within the limits for push ≤ 1 and cap 1; a little beyond them (what
    projection must cut back, by less than the phase's projection bound) otherwise."""
    amounts = np.array([draw(st.floats(*push)) for _ in range(6)]) * heading * A_STEP
    steps = moving + amounts * np.arange(1, horizon + 1)[:, None]
    return start + np.cumsum(np.clip(steps, -cap * V_STEP, cap * V_STEP), axis=0)


def late_braking(start: np.ndarray, horizon: int, moving: np.ndarray, heading: np.ndarray,
                 limits: tuple[np.ndarray, np.ndarray], late: float) -> np.ndarray:
    """A policy that drives each joint along ``heading`` toward its position limit and plans
    to stop there braking at ``late`` × the acceleration limit: from 1.0 (just in time) to
    1.5 (too late, what projection must correct by braking earlier)."""
    lower, upper = limits
    limit = np.where(heading > 0, upper, lower)
    q, speed, rows = start.copy(), moving * heading, []
    for _ in range(horizon):
        room = np.abs(limit - q)
        faster = np.minimum(speed + A_STEP, V_STEP)
        stop = faster + faster**2 / (2 * late * A_STEP)
        speed = np.where(stop <= room, faster, np.maximum(speed - late * A_STEP, 0.0))
        q = q + heading * speed
        rows.append(q)
    return np.array(rows)


@st.composite
def fast_actions(draw: st.DrawFn, start: np.ndarray, horizon: int,
                 moving: np.ndarray | None = None, wild: int = 6) -> np.ndarray:
    """From ``start`` (moving by ``moving`` per period), up to ``wild`` joints break a bound:
    a cruise at up to 1.5× the velocity limit from the first row (from rest, a change of step
    far beyond the acceleration limit), or a ramp whose step changes by up to 3× the
    acceleration limit per row; the other joints keep moving as they were. With all joints
    wild, maybe a kick of up to ±0.3 rad halfway."""
    base = np.zeros(6) if moving is None else moving
    steps = np.repeat(base[None, :], horizon, axis=0)
    chosen = draw(st.lists(st.integers(0, 5), min_size=1, max_size=wild, unique=True))
    for joint in chosen:
        if draw(st.booleans()):
            steps[:, joint] = draw(st.floats(-1.5, 1.5)) * V_STEP[joint]
        else:
            growth = draw(st.floats(-3.0, 3.0)) * A_STEP[joint]
            steps[:, joint] += growth * np.arange(1, horizon + 1)
    actions = start + np.cumsum(steps, axis=0)
    if wild == 6 and draw(st.booleans()):
        actions[horizon // 2:, draw(st.integers(0, 5))] += draw(st.floats(-0.3, 0.3))
    return actions


def into_limit(start: np.ndarray, heading: np.ndarray,
               limits: tuple[np.ndarray, np.ndarray], speed: float, horizon: int) -> np.ndarray:
    """Cruise at ``speed`` × the velocity limit along ``heading`` and stop dead at the position
    limit: projection must brake in time (by little enough, at low speed, to admit it)."""
    lower, upper = limits
    limit = np.where(heading > 0, upper, lower)
    ahead = start + speed * V_STEP * heading * np.arange(1, horizon + 1)[:, None]
    return np.where(heading > 0, np.minimum(ahead, limit), np.maximum(ahead, limit))


@st.composite
def policy_actions(draw: st.DrawFn, start: np.ndarray, moving: np.ndarray, heading: np.ndarray,
                   limits: tuple[np.ndarray, np.ndarray], horizon: int) -> np.ndarray:
    """One chunk of a policy at work, from the last action sent (``start``, ``moving``): legal,
    a little beyond the rate limits, far beyond them, braking late for a position limit, or
    driving into one."""
    kind = draw(st.sampled_from(["legal", "a little beyond", "far beyond", "brakes late",
                                 "drives into a limit"]))
    if kind == "drives into a limit":
        return into_limit(start, heading, limits, draw(st.floats(0.1, 0.5)), horizon)
    if kind == "brakes late":
        return late_braking(start, horizon, moving, heading, limits, draw(st.floats(1.0, 1.5)))
    if kind == "far beyond":
        return draw(fast_actions(start, horizon, moving, wild=1))
    if kind == "legal":
        return draw(pushed_actions(start, horizon, moving, heading, (0.3, 1.0), cap=1.0))
    return draw(pushed_actions(start, min(horizon, 3), moving, heading, (1.0, 2.0), cap=1.5))
