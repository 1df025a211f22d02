"""A RuleBasedStateMachine over random event streams, asserting the core's invariants.

- No action of a refused chunk is ever sent.
- No sent setpoint violates position, velocity or acceleration limits (on the action grid),
  and none is older than its phase allows.
- Every tick that is not a policy setpoint carries its reason.
- E_STOP always wins: until a reset, every tick stops and no chunk is admitted.
- The queue never holds actions of an old epoch.
"""

from __future__ import annotations

import os

import numpy as np
from hypothesis import event, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

from assurance.queue import Row
from kernel.core.effects import Motion, Retreat, Setpoint
from kernel.core.events import (
    ControllerEvent,
    ForceEvent,
    HandshakeEvent,
    LinkEvent,
    ObservationEvent,
    OodEvent,
    OperatorEvent,
    PhaseEvent,
    StateEvent,
)
from kernel.core.lines import ChunkLine, TickLine, TransitionLine
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
from tools.scenarios.base import EVIDENCE, offer

EPS = 1e-9
PHASES = ["FREE_SPACE", "PRE_CONTACT", "CONTACT", "VERIFY", "RETREAT", "SAFE_HOLD"]


class CoreMachine(RuleBasedStateMachine):
    @initialize()
    def start(self) -> None:
        self.config = core_config("FREE_SPACE")
        self.core = Core(self.config)
        self.t_ms = 0
        self.next_tick_ms = 0
        self.observations: list[tuple[str, int]] = []
        self.sent_fields: list[dict] = []
        self.sequence = 0
        self.accepted: set[str] = set()
        self.refused: set[str] = set()
        self.in_estop = False
        self.run: list[tuple[str, int, np.ndarray]] = []
        self.commanded: list[np.ndarray] = []

    # -- time ----------------------------------------------------------------------------------

    @rule(ms=st.integers(1, 40))
    def advance(self, ms: int) -> None:
        target = self.t_ms + ms
        while self.next_tick_ms <= target:
            row, step = tick(self.core, self.next_tick_ms * 1_000_000)
            self._check_lines(step.lines)
            self._check_row(row)
            self._check_motion(step.motion)
            self.next_tick_ms += PERIOD_MS
        self.t_ms = target

    @rule(ms=st.integers(1, 12))
    def advance_a_little(self, ms: int) -> None:
        self.advance(ms)

    def _feed(self, event) -> None:  # type: ignore[no-untyped-def]
        self._check_lines(feed(self.core, event))

    def _ns(self) -> int:
        return self.t_ms * 1_000_000

    # -- world events --------------------------------------------------------------------------

    @rule()
    def observe(self) -> None:
        name = f"O{len(self.observations) + 1}"
        self.observations.append((name, self.t_ms))
        self._feed(ObservationEvent(t=self._ns(), observation_id=name))

    @rule(noise=st.floats(-0.003, 0.003), jump=st.booleans())
    def state_sample(self, noise: float, jump: bool) -> None:
        q = self.core.state.measured_q.copy()
        if self.run:
            q = self.run[-1][2].copy()
        q[:6] += noise + (0.1 if jump else 0.0)
        self._feed(StateEvent(t=self._ns(), q=tuple(q.tolist())))

    @rule(data=st.data())
    def chunk(self, data: st.DataObject) -> None:
        state = self.core.state
        self.sequence += 1
        obs = data.draw(st.sampled_from([*self.observations[-3:], ("O-unknown", 0)]))
        phase = data.draw(st.sampled_from([str(state.task.phase), "PRE_CONTACT", "FREE_SPACE"]))
        epoch = state.epoch + data.draw(st.sampled_from([0, 0, 0, -1, 1]))
        first = self.t_ms + data.draw(st.integers(-30, 25))
        horizon = data.draw(st.integers(1, 12))
        speed = data.draw(st.floats(0.0, 2.0))
        start = (self.run[-1][2] if self.run else state.measured_q)[:6]
        steps = np.arange(1, horizon + 1)[:, None] * 0.004 * speed
        actions = start + steps * data.draw(st.sampled_from([1.0, -1.0]))
        if data.draw(st.booleans()):
            actions[horizon // 2:, 1] += data.draw(st.floats(-0.3, 0.3))
        policy = data.draw(st.sampled_from(["replace", "append", "blend"]))
        fields = chunk_fields(f"C{self.sequence}", self.sequence, epoch, phase, obs[0], obs[1],
                              first, actions, replacement_policy=policy)
        self.sent_fields.append(fields)
        self._feed(chunk_event(self.t_ms, fields))

    @rule(horizon=st.integers(2, 12), lead=st.integers(0, 12), speed=st.floats(0.0, 1.0),
          policy=st.sampled_from(["replace", "append", "blend"]))
    def healthy_chunk(self, horizon: int, lead: int, speed: float, policy: str) -> None:
        """A chunk made the way a good policy server makes them, so motion actually happens."""
        state = self.core.state
        if not self.observations or self.t_ms - self.observations[-1][1] > 30:
            self.observe()
        name, obs_t = self.observations[-1]
        self.sequence += 1
        start = (self.run[-1][2] if self.run else state.measured_q)[:6]
        actions = start + np.arange(1, horizon + 1)[:, None] * 0.004 * speed
        fields = chunk_fields(f"C{self.sequence}", self.sequence, state.epoch,
                              str(state.task.phase), name, obs_t, self.t_ms + lead, actions,
                              replacement_policy=policy)
        self.sent_fields.append(fields)
        self._feed(chunk_event(self.t_ms, fields))

    @rule(horizon=st.integers(2, 12), speed=st.floats(0.0, 1.0))
    def healthy_chunk_now(self, horizon: int, speed: float) -> None:
        self.healthy_chunk(horizon, 0, speed, "replace")

    @rule(to=st.sampled_from(["FREE_SPACE", "PRE_CONTACT"]))
    def recover(self, to: str) -> None:
        """What an operator and a reconnecting server do to get back to work."""
        t = self._ns()
        for event_ in (ControllerEvent(t=t, status="ok"), OperatorEvent(t=t, action="reset"),
                       OperatorEvent(t=t, action="release"),
                       OperatorEvent(t=t, action="accept_recovery"),
                       HandshakeEvent(t=t, offer=offer(queue_epoch=self.core.state.epoch)),
                       PhaseEvent(t=t, to=to, evidence={}, by="fsm")):
            self._feed(event_)

    @rule(data=st.data())
    def resend(self, data: st.DataObject) -> None:
        if self.sent_fields:
            fields = data.draw(st.sampled_from(self.sent_fields))
            self._feed(chunk_event(self.t_ms, fields))

    @rule(to=st.sampled_from(PHASES), full=st.booleans(), by=st.sampled_from(["fsm", "policy"]))
    def phase(self, to: str, full: bool, by: str) -> None:
        evidence = EVIDENCE if full else {}
        self._feed(PhaseEvent(t=self._ns(), to=to, evidence=evidence, by=by))

    @rule(residual=st.floats(-30, 30))
    def force(self, residual: float) -> None:
        self._feed(ForceEvent(t=self._ns(), residual=residual))

    @rule(score=st.floats(0, 1))
    def ood(self, score: float) -> None:
        self._feed(OodEvent(t=self._ns(), score=score))

    @rule(status=st.sampled_from(["down", "up"]))
    def link(self, status: str) -> None:
        self._feed(LinkEvent(t=self._ns(), status=status))

    @rule(compatible=st.booleans())
    def handshake(self, compatible: bool) -> None:
        body = offer(queue_epoch=self.core.state.epoch) if compatible else offer(action_dim=7)
        self._feed(HandshakeEvent(t=self._ns(), offer=body))

    @rule(action=st.sampled_from(["takeover", "release", "accept_recovery", "estop", "reset",
                                  "abort"]))
    def operator(self, action: str) -> None:
        self._feed(OperatorEvent(t=self._ns(), action=action))

    @rule(status=st.sampled_from(["ok", "reject", "fault", "estop"]))
    def controller(self, status: str) -> None:
        self._feed(ControllerEvent(t=self._ns(), status=status))

    # -- invariants ----------------------------------------------------------------------------

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
        if line.decision in ("accepted", "trimmed", "replaced", "blended"):
            assert not self.in_estop, "a chunk was admitted during E_STOP"
            self.accepted.add(line.chunk_id)
        elif line.decision == "rejected" and line.chunk_id not in self.accepted:
            self.refused.add(line.chunk_id)

    def _on_tick(self, line: TickLine) -> None:
        policy_setpoint = line.command == "setpoint" and line.owner == "policy"
        assert (line.reason is None) == policy_setpoint, line
        if self.in_estop:
            assert line.mode == "E_STOP" and line.command == "stop", line
        if line.sent is not None:
            assert line.sent.chunk_id not in self.refused, line

    def _check_motion(self, motion: Motion | None) -> None:
        """What reaches the arm, period by period, stays inside every limit (the interpolator
        and the planner shape it; the device's own stop or hold restarts the check)."""
        assert motion is not None, "a tick without its motion effect"
        if not isinstance(motion, Setpoint | Retreat):
            self.commanded = []
            return
        limits, dt = self.config.limits, PERIOD_MS / 1000
        arm = limits.arm_mask
        q = np.asarray(motion.q)
        assert np.all(q >= limits.lower[arm] - EPS) and np.all(q <= limits.upper[arm] + EPS)
        if motion.stiffness:  # a compliance target: the contact law's, from the measured pose
            self.commanded = []
            return
        self.commanded = [*self.commanded[-2:], q]
        if len(self.commanded) >= 2:
            step = np.abs(self.commanded[-1] - self.commanded[-2])
            assert np.all(step <= limits.velocity[arm] * dt * (1 + 1e-6) + 1e-9), step
        if len(self.commanded) == 3:
            a, b, c = self.commanded
            change = np.abs(c - 2 * b + a)
            assert np.all(change <= limits.acceleration[arm] * dt * dt * (1 + 1e-6) + 1e-9)
        if isinstance(motion, Setpoint) and motion.chunk_id is not None:
            assert motion.chunk_id not in self.refused, motion

    def _check_row(self, row: Row | None) -> None:
        if row is None:
            self.run = []
            return
        limits = self.config.limits
        q = np.asarray(row.q)
        assert np.all(q >= limits.lower - EPS) and np.all(q <= limits.upper + EPS)
        key = (row.segment.chunk_id, row.chunk_index)
        if self.run and (self.run[-1][0], self.run[-1][1]) == key:
            return
        self.run.append((*key, q))
        event("setpoint run length >= 3" if len(self.run) >= 3 else "setpoint sent")
        self._check_rates()
        age_ms = self.next_tick_ms - row.segment.t_obs / 1e6
        policy = self.core.state.card.policy
        unc_ms = self.config.clock_uncertainty_ns / 1e6
        assert age_ms + unc_ms <= policy.max_action_age_ns / 1e6 + 1e-6

    def _check_rates(self) -> None:
        limits, dt = self.config.limits, DT_MS / 1000
        arm = limits.arm_mask
        points = [q for _, _, q in self.run[-3:]]
        if len(points) >= 2:
            step = np.abs(points[-1] - points[-2])[arm]
            assert np.all(step <= limits.velocity[arm] * dt + 1e-7), step
        if len(points) == 3:
            change = np.abs(points[2] - 2 * points[1] + points[0])[arm]
            assert np.all(change <= limits.acceleration[arm] * dt * dt + 1e-7), change

    @invariant()
    def queue_holds_only_the_current_epoch(self) -> None:
        if hasattr(self, "core"):
            assert self.core.state.queue.epochs() <= {self.core.state.epoch}


CoreMachine.TestCase.settings = settings(
    max_examples=int(os.environ.get("CORE_MACHINE_EXAMPLES", "80")), stateful_step_count=60,
    deadline=None,
)
TestCoreMachine = CoreMachine.TestCase
