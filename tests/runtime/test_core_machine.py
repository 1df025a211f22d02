"""A RuleBasedStateMachine over random event streams, asserting the core's invariants.

The streams hold what a bad day brings: proposals at up to 1.5× the velocity limits with
accelerations beyond theirs, NaN and infinite actions, chunks in a foreign clock domain with and
without a measured sync, out-of-order sequences, resends, link loss, operator and controller
events. Invariants, judged from the cell's limits as the scenario file states them (not from
the core's projection):

- No action of a refused chunk is ever sent; no non-finite chunk, and no chunk in a clock
  domain that was never synced, is ever admitted.
- Within an epoch, admitted sequences strictly increase.
- No sent setpoint leaves the position limits, and consecutive sent actions keep each step
  within ``v·dt``, each change of step within ``a·dt²``, and every state able to brake to rest
  inside the position limits. None is older than its phase allows.
- Every tick that is not a policy setpoint carries its reason.
- E_STOP always wins: until a reset, every tick stops and no chunk is admitted.
- The queue never holds actions of an old epoch.

Every call to the core goes through the adapter in ``machine_setup`` (``feed``, ``tick``); the
invariants live in ``machine_checks``, the motions in ``motions``.
"""

from __future__ import annotations

import os

import numpy as np
from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

from kernel.core.events import (
    ClockSyncEvent,
    ControllerEvent,
    ControllerStatus,
    ForceEvent,
    HandshakeEvent,
    LinkEvent,
    ObservationEvent,
    OodEvent,
    OperatorEvent,
    PhaseEvent,
    StateEvent,
)
from kernel.core.runtime import Core
from skills.phases import TaskPhase
from skills.task_fsm import Requester
from tests.runtime.machine_checks import (
    SERVER_OFFSET_MS,
    SYNCED_DOMAIN,
    UNSYNCED_DOMAIN,
    SentCommandChecks,
)
from tests.runtime.machine_setup import (
    DT_MS,
    PERIOD_MS,
    chunk_event,
    chunk_fields,
    core_config,
    feed,
    tick,
)
from tests.runtime.motions import (
    STANDARD,
    TIGHT,
    fast_actions,
    into_limit,
    late_braking,
    policy_actions,
    position_limits,
    pushed_actions,
)
from tools.scenarios.base import EVIDENCE, offer

PHASES = ["FREE_SPACE", "PRE_CONTACT", "CONTACT", "VERIFY", "RETREAT", "SAFE_HOLD"]


class CoreMachine(SentCommandChecks, RuleBasedStateMachine):
    @initialize(data=st.data(), moving=st.booleans(), tight=st.booleans(),
                impact=st.floats(0.1, 0.5),
                heading=st.lists(st.sampled_from([1.0, -1.0]), min_size=6, max_size=6))
    def start(self, data: st.DataObject, moving: bool, tight: bool, impact: float,
              heading: list[float]) -> None:
        self.heading = np.array(heading)
        """Where the policy's streams push each joint: toward the velocity and position limits."""
        cell = TIGHT if tight else STANDARD
        self.lower, self.upper = position_limits(cell)
        self.config = core_config("FREE_SPACE", robot=cell)
        self.core = Core(self.config)
        self.t_ms = 0
        self.next_tick_ms = 0
        self.observations: list[tuple[str, int]] = []
        self.sent_fields: list[dict] = []
        self.fields_of: dict[str, dict] = {}
        self.sequence = 0
        self.ids = 0
        self.sequence_of: dict[str, int] = {}
        self.accepted: set[str] = set()
        self.refused: set[str] = set()
        self.never_admissible: dict[str, str] = {}
        self.last_admitted: dict[int, int] = {}
        self.synced = False
        self.in_estop = False
        self.run: list[tuple[str, int, np.ndarray]] = []
        self.commanded: list[np.ndarray] = []
        """The last motion effects' positions (what reached the arm), for the rate checks."""
        self.sent_keys: set[tuple[str, int]] = set()
        if moving:  # half the streams start with the arm at speed, heading for its limits
            for _ in range(3):
                self.state_sample(0.0, jump=False)
                actions = late_braking(self._start(), 10, self._step(), self.heading,
                                       (self.lower, self.upper), late=1.0)
                lead = self._lead_to_next_row()
                self._send(*self._current(actions, 2 if lead is None else lead))
                self.advance(30)
            for _ in range(3):  # then a policy that would stop dead at the limit (tight
                self.state_sample(0.0, jump=False)  # cell), or speed past the velocity limit
                if tight:
                    actions = into_limit(self._start(), self.heading, (self.lower, self.upper),
                                         impact, 10)
                else:
                    actions = data.draw(pushed_actions(self._start(), 2, self._step(),
                                                       self.heading, (1.0, 1.5), cap=1.5))
                lead = self._lead_to_next_row()
                self._send(*self._current(actions, 2 if lead is None else lead))
                self.advance(20)

    # -- time ----------------------------------------------------------------------------------

    @rule(ms=st.integers(1, 40))
    def advance(self, ms: int) -> None:
        target = self.t_ms + ms
        while self.next_tick_ms <= target:
            command, lines = tick(self.core, self.next_tick_ms * 1_000_000)
            self._check_lines(lines)
            self._check_command(command)
            self.next_tick_ms += PERIOD_MS
        self.t_ms = target

    @rule(ms=st.integers(1, 12))
    def advance_a_little(self, ms: int) -> None:
        self.advance(ms)

    def _feed(self, event_) -> None:  # type: ignore[no-untyped-def]
        self._check_lines(feed(self.core, event_))

    def _ns(self) -> int:
        return self.t_ms * 1_000_000

    # -- chunks --------------------------------------------------------------------------------

    def _start(self) -> np.ndarray:
        return (self.run[-1][2] if self.run else self.core.inspect_state().measured_q)[:6]

    def _fresh_observation(self) -> tuple[str, int]:
        """The latest observation, or a new one if it is old or already answered (a sound
        server answers each observation once: a second answer is OBSERVATION_ANSWERED)."""
        answered = {self.fields_of[c]["observation_id"] for c in self.accepted}
        if not self.observations or self.t_ms - self.observations[-1][1] > 30 or (
                self.observations[-1][0] in answered):
            self.observe()
        return self.observations[-1]

    def _next_id(self) -> str:
        self.ids += 1
        return f"C{self.ids}"

    def _send(self, fields: dict, sequence: int, why_never: str | None = None) -> None:
        self.sent_fields.append(fields)
        self.fields_of[fields["chunk_id"]] = fields
        self.sequence_of[fields["chunk_id"]] = sequence
        if why_never is not None:
            self.never_admissible[fields["chunk_id"]] = why_never
        self._feed(chunk_event(self.t_ms, fields))

    def _current(self, actions: np.ndarray, lead: int = 0, sequence: int | None = None,
                 **overrides: object) -> tuple[dict, int]:
        """A chunk for the current epoch and phase, conditioned on a fresh observation."""
        status = self.core.status()
        name, obs_t = self._fresh_observation()
        if sequence is None:
            self.sequence += 1
            sequence = self.sequence
        fields = chunk_fields(self._next_id(), sequence, status.epoch,
                              str(status.phase), name, obs_t, self.t_ms + lead, actions,
                              **overrides)
        return fields, sequence

    @rule(data=st.data())
    def chunk(self, data: st.DataObject) -> None:
        """Anything: unknown observations, other phases and epochs, late or early, fast."""
        status = self.core.status()
        self.sequence += 1
        obs = data.draw(st.sampled_from([*self.observations[-3:], ("O-unknown", 0)]))
        phase = data.draw(st.sampled_from([str(status.phase), "PRE_CONTACT", "FREE_SPACE"]))
        epoch = status.epoch + data.draw(st.sampled_from([0, 0, 0, -1, 1]))
        first = self.t_ms + data.draw(st.integers(-30, 25))
        actions = data.draw(fast_actions(self._start(), data.draw(st.integers(1, 12))))
        policy = data.draw(st.sampled_from(["replace", "append", "blend"]))
        fields = chunk_fields(self._next_id(), self.sequence, epoch, phase, obs[0], obs[1],
                              first, actions, replacement_policy=policy)
        self._send(fields, self.sequence)

    @rule(horizon=st.integers(2, 12), lead=st.integers(0, 12), speed=st.floats(0.0, 1.0),
          policy=st.sampled_from(["replace", "append", "blend"]))
    def healthy_chunk(self, horizon: int, lead: int, speed: float, policy: str) -> None:
        """A chunk made the way a good policy server makes them, so motion actually happens."""
        actions = self._start() + np.arange(1, horizon + 1)[:, None] * 0.004 * speed
        self._send(*self._current(actions, lead, replacement_policy=policy))

    @rule(horizon=st.integers(2, 12), speed=st.floats(0.0, 1.0))
    def healthy_chunk_now(self, horizon: int, speed: float) -> None:
        self.healthy_chunk(horizon, 0, speed, "replace")

    @rule(data=st.data(), lead=st.integers(0, 12),
          policy=st.sampled_from(["replace", "append", "blend"]))
    def fast_chunk(self, data: st.DataObject, lead: int, policy: str) -> None:
        """Right context, wrong motion: up to 1.5× the velocity limits, kicks and ramps
        beyond the acceleration limits. Projected, or refused as infeasible."""
        actions = data.draw(fast_actions(self._start(), data.draw(st.integers(1, 12))))
        self._send(*self._current(actions, lead, replacement_policy=policy))

    @rule(horizon=st.integers(1, 12), row=st.integers(0, 11), joint=st.integers(0, 5),
          bad=st.sampled_from([float("nan"), float("inf"), -float("inf")]))
    def nonfinite_chunk(self, horizon: int, row: int, joint: int, bad: float) -> None:
        actions = self._start() + np.arange(1, horizon + 1)[:, None] * 0.002
        actions[min(row, horizon - 1), joint] = bad
        self._send(*self._current(actions), why_never="NONFINITE")

    @rule(horizon=st.integers(2, 12), lead=st.integers(0, 12), synced=st.booleans())
    def foreign_clock_chunk(self, horizon: int, lead: int, synced: bool) -> None:
        """Times in the server's clock (t_server = t_client − offset); without a sync of that
        domain the chunk can never be admitted."""
        _, obs_t = self._fresh_observation()
        actions = self._start() + np.arange(1, horizon + 1)[:, None] * 0.002
        shift = -SERVER_OFFSET_MS
        fields, sequence = self._current(
            actions, lead, clock_domain=SYNCED_DOMAIN if synced else UNSYNCED_DOMAIN,
            first_action_time=self.t_ms + lead + shift, inference_start=obs_t + 2 + shift,
            observation_event_time=obs_t + shift)
        never = None if synced and self.synced else "CLOCK_INVALID"  # never synced
        self._send(fields, sequence, why_never=never)

    @rule(round_trip_ms=st.integers(0, 20))
    def clock_sync(self, round_trip_ms: int) -> None:
        self.synced = True
        self._feed(ClockSyncEvent(t=self._ns(), domain=SYNCED_DOMAIN,
                                  offset=SERVER_OFFSET_MS * 1_000_000,
                                  round_trip=round_trip_ms * 1_000_000))

    @rule(horizon=st.integers(2, 12), speed=st.floats(0.0, 1.0))
    def out_of_order_pair(self, horizon: int, speed: float) -> None:
        """Two chunks produced in order, delivered swapped: the older one is REORDERED if the
        newer was admitted."""
        actions = self._start() + np.arange(1, horizon + 1)[:, None] * 0.004 * speed
        older, newer = self.sequence + 1, self.sequence + 2
        self.sequence += 2
        self._send(*self._current(actions, sequence=newer))
        self._send(*self._current(actions, sequence=older))

    @rule(back=st.integers(0, 3), horizon=st.integers(2, 12))
    def stale_sequence(self, back: int, horizon: int) -> None:
        """A new chunk id carrying a sequence already used (or older)."""
        actions = self._start() + np.arange(1, horizon + 1)[:, None] * 0.002
        self._send(*self._current(actions, sequence=max(0, self.sequence - back)))

    @rule(data=st.data(), bursts=st.integers(1, 10))
    def policy_stream(self, data: st.DataObject, bursts: int) -> None:
        """A policy at work: chunks (good ones, and ones a little or far beyond the limits)
        with ticks in between, so that setpoints flow long enough to be judged."""
        for _ in range(bursts):
            self.state_sample(0.0, jump=False)  # the arm follows: no divergence from drift
            horizon = data.draw(st.integers(1, 10))
            actions = data.draw(policy_actions(self._start(), self._step(), self.heading,
                                               (self.lower, self.upper), horizon))
            lead = self._lead_to_next_row()
            if lead is None or data.draw(st.integers(0, 4)) == 0:  # now and then, off the grid
                lead = data.draw(st.integers(0, 12))
            self._send(*self._current(actions, lead))
            self.advance(data.draw(st.integers(4, 20)))

    def _lead_to_next_row(self) -> int | None:
        """How long until the action after the last one sent is due: a policy that continues
        the motion starts its chunk there (the rows up to it are already queued)."""
        if not self.run:
            return None
        chunk_id, index, _ = self.run[-1]
        fields = self.fields_of[chunk_id]
        if fields["clock_domain"] != "client":
            return None
        return max(0, int(fields["first_action_time"]) + (index + 1) * DT_MS - self.t_ms)

    def _step(self) -> np.ndarray:
        """The step of the last two actions sent (zero at rest)."""
        if len(self.run) < 2:
            return np.zeros(6)
        return self.run[-1][2] - self.run[-2][2]

    @rule(data=st.data())
    def resend(self, data: st.DataObject) -> None:
        if self.sent_fields:
            fields = data.draw(st.sampled_from(self.sent_fields))
            self._feed(chunk_event(self.t_ms, fields))

    # -- world events --------------------------------------------------------------------------

    @rule()
    def observe(self) -> None:
        name = f"O{len(self.observations) + 1}"
        self.observations.append((name, self.t_ms))
        self._feed(ObservationEvent(t=self._ns(), observation_id=name))

    @rule(noise=st.floats(-0.003, 0.003), jump=st.booleans())
    def state_sample(self, noise: float, jump: bool) -> None:
        q = self.core.inspect_state().measured_q.copy()
        if self.run:
            q = self.run[-1][2].copy()
        q[:6] += noise + (0.1 if jump else 0.0)
        self._feed(StateEvent(t=self._ns(), q=tuple(q.tolist())))

    @rule(joint=st.integers(0, 5), side=st.sampled_from([1.0, -1.0]),
          room=st.floats(0.0, 0.05))
    def near_a_limit(self, joint: int, side: float, room: float) -> None:
        """The arm measured close to a position limit: chunks now start there."""
        q = self.core.inspect_state().measured_q.copy()
        q[joint] = (self.upper[joint] if side > 0 else self.lower[joint]) - side * room
        self._feed(StateEvent(t=self._ns(), q=tuple(q.tolist())))

    @rule(to=st.sampled_from(["FREE_SPACE", "PRE_CONTACT"]))
    def recover(self, to: str) -> None:
        """What an operator and a reconnecting server do to get back to work."""
        t = self._ns()
        for event_ in (ControllerEvent(t=t, status=ControllerStatus.OK),
                       OperatorEvent(t=t, action="reset"),
                       OperatorEvent(t=t, action="release"),
                       OperatorEvent(t=t, action="accept_recovery"),
                       HandshakeEvent(t=t, offer=offer(queue_epoch=self.core.status().epoch)),
                       PhaseEvent(t=t, to=TaskPhase(to), evidence={}, by=Requester.FSM)):
            self._feed(event_)

    @rule(to=st.sampled_from(PHASES), full=st.booleans(),
          by=st.sampled_from([Requester.FSM, Requester.POLICY]))
    def phase(self, to: str, full: bool, by: Requester) -> None:
        evidence = EVIDENCE if full else {}
        self._feed(PhaseEvent(t=self._ns(), to=TaskPhase(to), evidence=evidence, by=by))

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
        body = offer(queue_epoch=self.core.status().epoch) if compatible else offer(action_dim=7)
        self._feed(HandshakeEvent(t=self._ns(), offer=body))

    @rule(action=st.sampled_from(["takeover", "release", "accept_recovery", "estop", "reset",
                                  "abort"]))
    def operator(self, action: str) -> None:
        self._feed(OperatorEvent(t=self._ns(), action=action))

    @rule(status=st.sampled_from(["ok", "reject", "fault", "estop"]))
    def controller(self, status: str) -> None:
        self._feed(ControllerEvent(t=self._ns(), status=ControllerStatus(status)))

    @invariant()
    def queue_holds_only_the_current_epoch(self) -> None:
        if hasattr(self, "core"):
            assert self.core.inspect_state().queue.epochs() <= {self.core.status().epoch}


CoreMachine.TestCase.settings = settings(
    max_examples=int(os.environ.get("CORE_MACHINE_EXAMPLES", "80")), stateful_step_count=60,
    deadline=None,
)
TestCoreMachine = CoreMachine.TestCase
