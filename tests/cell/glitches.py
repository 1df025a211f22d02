"""Reading glitches injected into a running cell, and how far the true arm moved meanwhile.

A :class:`GlitchCampaign` is a run's tick hook. It injects each planned glitch (an offset on
one joint's reported position, from the emulator's side: the plant never moves by it) when
the cell reaches the glitch's phase, then samples the plant's true joints over the emulator's
control port every tick until the glitch is over and the arm is back in the core's hands or
at rest: the window ends when the fallback leaves SAFE_HOLD (the operator's recovery hands the
arm back to the task, which then moves it on purpose) or ``settle_s`` after the glitch, and
never before the glitch has ended. Each window records the true state at the onset and the
largest excursion of every joint from it.

Used by tests/cell/test_reading_glitch.py (which asserts) and bench/reading_glitch.py (which
prints, for this checkout or another one); it reads the run only through the tick hook's
context, so it works on any revision that has the hook.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

TRANSPORT, PRE_CONTACT, CONTACT, HOLD = "transport", "pre-contact", "contact", "hold"
PHASES = (TRANSPORT, PRE_CONTACT, CONTACT, HOLD)


@dataclass
class Glitch:
    phase: str
    """When to inject: during the transport move, while the policy streams pre-contact chunks,
    during the insertion (CONTACT), or in a SAFE_HOLD."""
    spec: dict[str, Any]
    """``{"samples": N}`` or ``{"duration_ms": D}``."""
    joint: int = 0
    offset: float = 0.5
    lasts_s: float | None = None
    """How long a glitch given in samples lasts (one sample a period, on a virtual clock)."""
    injected_ns: int | None = None
    ends_ns: int | None = None
    closed_ns: int | None = None
    q0: np.ndarray | None = None
    qd0: np.ndarray | None = None
    a0: np.ndarray | None = None
    """True acceleration at the onset, from the last two true samples before it."""
    excursion: np.ndarray | None = None
    """Per joint: the largest distance of the true joint from where it was at the onset."""
    modes: list[str] = field(default_factory=list)
    """Fallback modes seen during the window, in order (no repeats)."""
    trace: list[tuple[int, np.ndarray, np.ndarray]] = field(default_factory=list)
    """The true joints over the window: (plant time ns, q, qd) per tick."""

    @property
    def label(self) -> str:
        length = (f"{self.spec['samples']} sample" if "samples" in self.spec
                  else f"{self.spec['duration_ms']:g} ms")
        return f"{self.phase}/{length}"

    @property
    def duration_s(self) -> float:
        if self.lasts_s is not None:
            return self.lasts_s
        return float(self.spec.get("duration_ms", 0.0)) * 1e-3


class GlitchCampaign:
    """The tick hook: returns True (end the run) once every glitch's window has closed.

    One glitch is injected at a time (the next only once the last one has ended); windows may
    overlap, so that a hold glitch can land in the SAFE_HOLD an earlier glitch caused, before
    the operator's recovery ends it."""

    def __init__(self, glitches: list[Glitch], settle_s: float = 0.6,
                 give_up_s: float = 60.0) -> None:
        self.glitches = glitches
        self.settle_s, self.give_up_s = settle_s, give_up_s
        self._open: list[Glitch] = []
        self._started_ns: int | None = None
        self._phase_since: dict[str, int] = {}
        self._last_truth: tuple[int, np.ndarray, np.ndarray] | None = None

    @property
    def done(self) -> bool:
        return all(g.closed_ns is not None for g in self.glitches)

    def __call__(self, context: Any) -> bool:
        cell = context.cell
        now = cell.gateway.now_ns()
        self._started_ns = self._started_ns if self._started_ns is not None else now
        self._track_phases(cell, now)
        truth = None
        if self._open or self._wants_truth():
            truth = self._truth(cell)
            self._measure(cell, now, truth)
        busy = any(g.ends_ns is not None and now < g.ends_ns for g in self._open)
        pending = None if busy else next(
            (g for g in self.glitches if g.injected_ns is None and self._due(g, now)), None)
        if pending is not None:
            self._inject(pending, cell, now)
        elif truth is not None:
            self._last_truth = truth
        return self.done or (now - self._started_ns) * 1e-9 > self.give_up_s

    # -- when ------------------------------------------------------------------------------

    def _phase(self, cell: Any) -> str | None:
        state = cell.core.inspect_state()  # the queue's pending rows: no status carries them
        if state.fallback.mode == "SAFE_HOLD":
            return HOLD
        if state.fallback.mode != "RUNNING":
            return None
        step = cell.controller.runner.step
        if step == "transport":
            return TRANSPORT
        if step == "pre-contact" and state.queue.pending_rows(cell.gateway.now_ns()) > 0:
            return PRE_CONTACT
        if step == "insert" and state.task.phase == "CONTACT":
            return CONTACT
        return None

    def _track_phases(self, cell: Any, now: int) -> None:
        phase = self._phase(cell)
        self._phase_since = {phase: self._phase_since.get(phase, now)} if phase else {}

    def _due(self, glitch: Glitch, now: int) -> bool:
        """In the glitch's phase for a while: the transport under way, the insertion begun,
        the hold settling; pre-contact as soon as chunks stream."""
        since = self._phase_since.get(glitch.phase)
        delay = {TRANSPORT: 0.25, PRE_CONTACT: 0.0, CONTACT: 0.1, HOLD: 0.25}[glitch.phase]
        return since is not None and (now - since) * 1e-9 >= delay and (
            self._last_truth is not None)

    def _wants_truth(self) -> bool:
        """Sample the truth ahead of an injection that may come (its acceleration needs two)."""
        return any(g.injected_ns is None and g.phase in self._phase_since for g in self.glitches)

    # -- what happened ---------------------------------------------------------------------

    def _inject(self, glitch: Glitch, cell: Any, now: int) -> None:
        before = self._last_truth
        t0, q0, qd0 = self._truth(cell)
        cell.world.inject("reading_glitch", joint=glitch.joint, offset=glitch.offset,
                          **glitch.spec)
        glitch.injected_ns = now
        glitch.ends_ns = now + round(max(glitch.duration_s, 0.0) * 1e9)
        glitch.q0, glitch.qd0 = q0, qd0
        if before is not None and t0 > before[0]:
            glitch.a0 = (qd0 - before[2]) / ((t0 - before[0]) * 1e-9)
        else:
            glitch.a0 = np.zeros_like(qd0)
        glitch.excursion = np.zeros_like(q0)
        glitch.modes = [str(cell.core.status().mode)]
        self._open.append(glitch)
        self._last_truth = None

    def _measure(self, cell: Any, now: int, truth: tuple[int, np.ndarray, np.ndarray]) -> None:
        mode = str(cell.core.status().mode)
        for glitch in list(self._open):
            if glitch.q0 is None or glitch.excursion is None:
                continue
            glitch.excursion = np.maximum(glitch.excursion, np.abs(truth[1] - glitch.q0))
            glitch.trace.append(truth)
            if mode != glitch.modes[-1]:
                glitch.modes.append(mode)
            over = glitch.ends_ns is not None and now >= glitch.ends_ns
            recovered = "SAFE_HOLD" in glitch.modes and mode != "SAFE_HOLD"
            settled = (now - (glitch.ends_ns or now)) * 1e-9 >= self.settle_s
            if over and (recovered or settled):
                glitch.closed_ns = now
                self._open.remove(glitch)

    @staticmethod
    def _truth(cell: Any) -> tuple[int, np.ndarray, np.ndarray]:
        truth = cell.world.inject("ground_truth")
        return int(truth["t_ns"]), np.array(truth["q"]), np.array(truth["qd"])


def braking_distance(v0: float, a0: float, a_max: float, jerk: float, dt: float = 1e-4) -> float:
    """How far a joint moving at ``v0`` with acceleration ``a0`` (along its motion) travels
    before rest, braking as hard as ``a_max`` and ``jerk`` allow: the acceleration falls at
    the jerk limit to -a_max and is released at the jerk limit so as to reach rest with zero
    acceleration. Written from the limits alone (step by step), not from warden's code."""
    v, a, distance = abs(v0), float(np.clip(a0 if v0 >= 0 else -a0, -a_max, a_max)), 0.0
    while v > 0.0 or a > 0.0:
        # release the brake when the remaining speed is what ramping |a| to 0 removes
        releasing = a < 0.0 and v <= a * a / (2.0 * jerk)
        a = min(a + jerk * dt, 0.0) if releasing else max(a - jerk * dt, -a_max)
        v = max(v + a * dt, 0.0)
        distance += v * dt
        if releasing and a == 0.0:
            break
    return distance


@dataclass(frozen=True)
class Commanded:
    """The last command before a glitch's onset, from the run's journal: where the arm was
    told to be, and how fast that was moving (from the commands before it)."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray


def last_command(journal: list[dict[str, Any]], t_ms: float, period_s: float
                 ) -> Commanded | None:
    """The last position command journaled at or before ``t_ms`` and its rates.

    The rates are per control period, not per journaled wall time: each command is the
    setpoint one period after the one before (warden's interpolator and planner advance one
    period a tick, however late the tick), so a loaded machine spreads the same path over more
    wall time without changing where braking it ends. Measured over the wall time between the
    journal's ticks (3-4 ms apart at load 6 instead of 2 ms), a transport move's velocity
    came out half and its acceleration a quarter of the path's, and the braking bound a
    tenth of the braking that path takes (0.013 rad against 0.124 rad)."""
    moves = [np.array(e["effect"]["q"]) for e in journal
             if e.get("kind") == "command" and e["t"] <= t_ms and e["effect"].get("q")]
    if len(moves) < 3:
        return None
    q0, q1, q2 = moves[-3:]
    v1, v2 = (q1 - q0) / period_s, (q2 - q1) / period_s
    return Commanded(q2, v2, (v2 - v1) / period_s)


def motion_from(glitch: Glitch, where: np.ndarray) -> np.ndarray:
    """Per joint: the largest distance of the true joint from ``where`` over the window."""
    if not glitch.trace:
        return np.zeros_like(where)
    return np.max([np.abs(q - where) for _, q, _ in glitch.trace], axis=0)
