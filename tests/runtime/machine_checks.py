"""The invariants the core state machine checks on every line and command the core produces.

A mixin for :class:`tests.runtime.test_core_machine.CoreMachine`, kept apart so that what the
machine does and what it asserts can each be read on their own. Limits are the cell's as the
scenario file states them (``tests.runtime.motions``), never the core's own.
"""

from __future__ import annotations

import numpy as np
from hypothesis import event

from kernel.core.config import CoreConfig
from kernel.core.effects import Motion, Retreat, Setpoint
from kernel.core.lines import ChunkLine, TickLine, TransitionLine
from kernel.core.runtime import Core
from tests.core.projection_oracle import stopping_position
from tests.runtime.machine_setup import PERIOD_MS
from tests.runtime.motions import A_STEP, V_STEP

EPS = 1e-9
RATE_TOLERANCE = 1e-7  # the actions are rounded to 1e-9 rad on the way in (chunk_fields)
ADMITTED = ("accepted", "trimmed", "replaced", "blended")
WATCHED = {"NONFINITE", "CLOCK_INVALID", "REORDERED", "INFEASIBLE"}
"""Refusal reasons whose share the statistics report (``--hypothesis-show-statistics``)."""
SYNCED_DOMAIN, UNSYNCED_DOMAIN = "server", "gpu"
SERVER_OFFSET_MS = -7000  # t_client = t_server + offset


class SentCommandChecks:
    """State the checks read (set up by the machine's ``start``)."""

    core: Core
    config: CoreConfig
    lower: np.ndarray
    upper: np.ndarray
    next_tick_ms: int
    fields_of: dict[str, dict]
    sequence_of: dict[str, int]
    accepted: set[str]
    refused: set[str]
    never_admissible: dict[str, str]
    """Chunk id → the reason code its refusal must carry (it can never be admitted)."""
    last_admitted: dict[int, int]
    in_estop: bool
    run: list[tuple[str, int, np.ndarray]]
    commanded: list[np.ndarray]
    sent_keys: set[tuple[str, int]]

    def _check_lines(self, lines: list) -> None:  # type: ignore[type-arg]
        for line in lines:
            if isinstance(line, ChunkLine):
                self._on_chunk(line)
            elif isinstance(line, TransitionLine) and line.machine == "fallback" and (
                line.accepted
            ):
                if line.to == "E_STOP":
                    self.in_estop = True
                elif line.from_ == "E_STOP":
                    self.in_estop = False
            elif isinstance(line, TickLine):
                self._on_tick(line)

    def _on_chunk(self, line: ChunkLine) -> None:
        event(f"chunk {line.decision}")
        if line.decision in ADMITTED and (line.projection_distance or 0) > 0:
            event("chunk admitted after projection")
        required = self.never_admissible.get(line.chunk_id)
        if required is not None and line.decision != "ignored":  # (a resend is ignored)
            assert line.decision == "rejected" and required in line.reasons, (line, required)
        if line.decision in ADMITTED:
            assert not self.in_estop, "a chunk was admitted during E_STOP"
            sequence = self.sequence_of[line.chunk_id]
            last = self.last_admitted.get(line.queue_epoch)
            assert last is None or sequence > last, (line, sequence, last)
            self.last_admitted[line.queue_epoch] = sequence
            self.accepted.add(line.chunk_id)
        elif line.decision == "rejected" and line.chunk_id not in self.accepted:
            self.refused.add(line.chunk_id)
            for code in set(line.reasons) & WATCHED:
                event(f"refused with {code}")

    def _on_tick(self, line: TickLine) -> None:
        policy_setpoint = line.command == "setpoint" and line.owner == "policy"
        assert (line.reason is None) == policy_setpoint, line
        if self.in_estop:
            assert line.mode == "E_STOP" and line.command == "stop", line
        if line.sent is not None:
            assert line.sent.chunk_id not in self.refused, line

    def _check_command(self, command) -> None:  # type: ignore[no-untyped-def]
        self._check_motion(command.motion)
        if command.sent is None:
            self.run = []
            return
        q = np.asarray(command.target)[:6]
        assert np.all(q >= self.lower - EPS) and np.all(q <= self.upper + EPS), q
        key = (command.sent.chunk_id, command.sent.index)
        if self.run and (self.run[-1][0], self.run[-1][1]) == key:
            return
        self.run.append((*key, q))
        self.sent_keys.add(key)
        event("setpoint run length >= 3" if len(self.run) >= 3 else "setpoint sent")
        if np.any(np.minimum(q - self.lower, self.upper - q) < 0.05):
            event("setpoint within 0.05 rad of a position limit")
        self._check_rates()
        age_ms = self.next_tick_ms - command.t_obs / 1e6
        policy = self.core.inspect_state().card.policy
        unc_ms = self.config.clock_uncertainty_ns / 1e6
        assert age_ms + unc_ms <= policy.max_action_age_ns / 1e6 + 1e-6

    def _check_motion(self, motion: Motion | None) -> None:
        """What reaches the arm, period by period, stays inside the position, velocity and
        acceleration limits (the interpolator shapes policy actions and holds, the planner its
        moves). A device stop or hold, and a compliance target of the contact law (it starts
        where the arm is measured), restart the check."""
        assert motion is not None, "a tick without its motion effect"
        if not isinstance(motion, Setpoint | Retreat):
            self.commanded = []
            return
        q = np.asarray(motion.q)
        assert np.all(q >= self.lower - EPS) and np.all(q <= self.upper + EPS), q
        if motion.stiffness:
            self.commanded = []
            return
        dt = PERIOD_MS / 1000
        arm = self.config.limits.arm_mask
        velocity, acceleration = (self.config.limits.velocity[arm],
                                  self.config.limits.acceleration[arm])
        self.commanded = [*self.commanded[-2:], q]
        if len(self.commanded) >= 2:
            step = np.abs(self.commanded[-1] - self.commanded[-2])
            assert np.all(step <= velocity * dt * (1 + 1e-6) + 1e-9), step
        if len(self.commanded) == 3:
            a, b, c = self.commanded
            assert np.all(np.abs(c - 2 * b + a) <= acceleration * dt * dt * (1 + 1e-6) + 1e-9)
        if isinstance(motion, Setpoint) and motion.chunk_id is not None:
            assert motion.chunk_id not in self.refused, motion

    def _check_rates(self) -> None:
        points = [q for _, _, q in self.run[-3:]]
        if len(points) < 2:
            return
        step = points[-1] - points[-2]
        assert np.all(np.abs(step) <= V_STEP + RATE_TOLERANCE), step
        if np.any(np.abs(step) > 0.9 * V_STEP):
            event("a step above 0.9x the velocity limit sent")
        if len(points) == 3:
            change = step - (points[1] - points[0])
            assert np.all(np.abs(change) <= A_STEP + RATE_TOLERANCE), change
        for joint in range(6):
            lo, hi = float(self.lower[joint]), float(self.upper[joint])
            rest = stopping_position(float(points[-1][joint]), float(step[joint]),
                                     float(A_STEP[joint]), lo, hi)
            assert lo - RATE_TOLERANCE <= rest <= hi + RATE_TOLERANCE, (joint, rest)

