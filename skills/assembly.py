"""One tabletop assembly cycle: acquire → grasp → transport → pre-contact → insert → verify →
retreat, driven tick by tick.

The runner owns the cycle's sequence and its evidence, never the motion: each tick it looks at
the measured state and at what the core reports (phase, fallback state, the progress of its
classical move, the contact owner's state) and may ask the core for something: a phase
transition (with the evidence a guarded one needs), a classical move to a joint target (solved
here from a tool pose), the gripper's opening, the contact owner's descent. Every request
reaches the core as an event, so it is journaled and replayed; the core decides, and plays
moves and descents itself. The runner adapts to what was decided.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Protocol

import numpy as np

from assurance.fallback import Mode
from skills.contact import ContactState, DescentStatus
from skills.evaluator import Evaluator, InsertionEvidence, InsertionVerdict
from skills.layout import CellLayout
from skills.phases import TaskPhase
from skills.planner import MoveStatus, Planner, PlanningError

P = TaskPhase


class AssemblyStep(StrEnum):
    START = "start"
    PICK_APPROACH = "pick approach"
    PICK_DESCEND = "pick descend"
    GRASP = "grasp"
    LIFT = "lift"
    TRANSPORT = "transport"
    APPROACH = "pre-contact"
    INSERT = "insert"
    VERIFY = "verify"
    RELEASE = "release"
    RETREAT_LIFT = "retreat lift"
    RETREAT_HOME = "retreat home"
    DONE = "done"


@dataclass(frozen=True, slots=True)
class CycleTiming:
    grasp_s: float = 0.35
    release_s: float = 0.25
    approach_timeout_s: float = 8.0
    """Time the policy has to bring the part over the hole, counted only while the core is
    RUNNING: a fallback's hold (a human recovering, a reconnection) is not the policy's time."""
    insert_timeout_s: float = 4.0
    request_interval_s: float = 0.1
    settle_rad: float = 0.0015
    """A classical move is done when every joint is this close to its end and at rest: a grasp
    closed on a still-settling arm holds the peg off-centre, more than the hole's clearance."""
    at_rest_rad_s: float = 0.05
    pose_tolerance_m: float = 0.001
    pose_height_tolerance_m: float = 0.003
    rotation_tolerance_rad: float = 0.02
    envelope_force_n: float = 6.0
    insert_short_of_bottom_m: float = 0.003
    """The descent ends this far above the hole's bottom: bottoming out is an impact."""


@dataclass(frozen=True, slots=True, eq=False)
class Sensed:
    t_ns: int
    q: np.ndarray
    qd: np.ndarray
    force_norm: float
    fresh: bool
    """A new state sample (with its wrench) arrived for this tick."""
    driver_ok: bool


class CoreView(Protocol):
    """What the runner reads of the core (its status, as of the last event)."""

    @property
    def phase(self) -> TaskPhase: ...
    @property
    def mode(self) -> Mode: ...
    @property
    def move_id(self) -> int: ...
    @property
    def move(self) -> MoveStatus: ...
    @property
    def contact(self) -> ContactState: ...
    @property
    def descent(self) -> DescentStatus: ...


@dataclass(frozen=True, slots=True)
class PhaseRequest:
    to: TaskPhase
    evidence: dict[str, bool]


@dataclass(frozen=True, slots=True, eq=False)
class MoveRequest:
    """A classical rest-to-rest move to a joint target."""

    move_id: int
    target: np.ndarray


@dataclass(frozen=True, slots=True)
class GripperRequest:
    opening: float


@dataclass(frozen=True, slots=True, eq=False)
class InsertRequest:
    """The contact owner's descent along the vertical through ``xy`` down to ``z_end``."""

    xy: np.ndarray
    z_end: float
    rotation: np.ndarray


Request = PhaseRequest | MoveRequest | GripperRequest | InsertRequest


@dataclass(frozen=True, slots=True)
class Outcome:
    verified: bool
    depth_m: float
    reason: str


class AssemblyRunner:
    def __init__(
        self, layout: CellLayout, planner: Planner, evaluator: Evaluator,
        ground_truth: Callable[[], float] | None = None, timing: CycleTiming | None = None,
    ) -> None:
        """``ground_truth``: a simulator's true insertion depth, an extra check for VERIFY
        (None on a real cell: the measured evidence alone decides)."""
        self.layout, self.planner = layout, planner
        self.evaluator, self.ground_truth = evaluator, ground_truth
        self.timing = timing or CycleTiming()
        self.step = AssemblyStep.DONE
        self.outcome: Outcome | None = None
        self._moves = 0
        self._move_target: np.ndarray | None = None
        self._view: CoreView | None = None
        self._requests: list[Request] = []
        self._since_ns = 0
        self._seen_ns = 0
        """The instant of the previous update (a paused step's clock moves on from it)."""
        self._last_request_ns = -(10**18)
        self._failure = ""
        self._peak_force_n = 0.0
        self._depth_m = 0.0

    # -- driven by the cell ----------------------------------------------------------------

    def begin(self, t_ns: int) -> None:
        self._enter(AssemblyStep.START, t_ns)
        self.outcome, self._failure = None, ""
        self._move_target = None
        self._peak_force_n, self._depth_m = 0.0, 0.0
        self._requests.append(GripperRequest(self.layout.gripper_open))

    @property
    def done(self) -> bool:
        return self.step is AssemblyStep.DONE

    def update(self, sensed: Sensed, view: CoreView) -> list[Request]:
        """Advance the cycle; returns what to ask the core for (in order)."""
        self._view = view
        if self.step is AssemblyStep.APPROACH and view.mode is not Mode.RUNNING:
            self._since_ns += sensed.t_ns - self._seen_ns  # the approach's clock is paused
        self._seen_ns = sensed.t_ns
        if self.step is not AssemblyStep.DONE:
            handler = _HANDLERS.get(self.step, AssemblyRunner._planned_step)
            request = handler(self, sensed, view.phase, view.mode)
            if request is not None:
                self._requests.append(request)
        requests, self._requests = self._requests, []
        return requests

    # -- steps -------------------------------------------------------------------------------

    def _start(self, s: Sensed, phase: TaskPhase, mode: Mode) -> PhaseRequest | None:
        if phase is P.FREE_SPACE:
            self._plan(AssemblyStep.PICK_APPROACH, s,
                       self.layout.tcp_above(self.layout.grasp_tcp, 0.1))
            return None
        target = {P.IDLE: P.VALIDATE, P.VALIDATE: P.FREE_SPACE}.get(phase)
        return self._request(target, s, mode) if target else None

    def _planned_step(self, s: Sensed, phase: TaskPhase, mode: Mode) -> PhaseRequest | None:
        view, target = self._view, self._move_target
        if view is None or target is None or view.move_id != self._moves:
            return None
        if view.move is MoveStatus.REFUSED:
            return self._fail(f"the planner refused the {self.step} move", s, mode)
        if view.move is not MoveStatus.FINISHED or not self._at_rest(s) or np.abs(
            s.q - target
        ).max() > self.timing.settle_rad:
            return None
        return _AFTER_MOVE[self.step](self, s, phase, mode)

    def _after_pick_approach(self, s: Sensed, phase: TaskPhase, mode: Mode) -> None:
        self._plan(AssemblyStep.PICK_DESCEND, s, self.layout.grasp_tcp)

    def _after_pick_descend(self, s: Sensed, phase: TaskPhase, mode: Mode) -> None:
        self._requests.append(GripperRequest(self.layout.gripper_closed))
        self._enter(AssemblyStep.GRASP, s.t_ns)

    def _grasp(self, s: Sensed, phase: TaskPhase, mode: Mode) -> None:
        if self._elapsed(s) >= self.timing.grasp_s:
            lift = self.layout.tcp_above(self.layout.peg_start, self.layout.clearance_height)
            self._plan(AssemblyStep.LIFT, s, lift)

    def _after_lift(self, s: Sensed, phase: TaskPhase, mode: Mode) -> None:
        self._plan(AssemblyStep.TRANSPORT, s, self.layout.staging_tcp)

    def _after_transport(self, s: Sensed, phase: TaskPhase, mode: Mode) -> PhaseRequest | None:
        if phase is P.PRE_CONTACT:
            self._move_target = None
            self._enter(AssemblyStep.APPROACH, s.t_ns)
            return None
        return self._request(P.PRE_CONTACT, s, mode)

    def _approach(self, s: Sensed, phase: TaskPhase, mode: Mode) -> Request | None:
        if phase is P.CONTACT:
            layout = self.layout
            bottom = layout.pre_insert_tcp[2] - layout.pre_insert_gap - (
                layout.hole_depth - self.timing.insert_short_of_bottom_m)
            self._enter(AssemblyStep.INSERT, s.t_ns)
            return InsertRequest(layout.hole_top[:2], float(bottom), layout.tool_down)
        if self._elapsed(s) > self.timing.approach_timeout_s:
            return self._fail("pre-contact approach timed out", s, mode)
        evidence = self.contact_evidence(s)
        if phase is P.PRE_CONTACT and evidence["pose_within_tolerance"] and self._at_rest(s):
            return self._request(P.CONTACT, s, mode, evidence)
        return None

    def _insert(self, s: Sensed, phase: TaskPhase, mode: Mode) -> PhaseRequest | None:
        self._peak_force_n = max(self._peak_force_n, s.force_norm)
        if phase is P.VERIFY:
            self._enter(AssemblyStep.VERIFY, s.t_ns)
            return None
        if phase is P.PRE_CONTACT:  # a hold interrupted contact: the insertion is not resumed
            return self._fail("insertion interrupted by a fallback", s, mode)
        contact = self._view.contact if self._view is not None else ContactState.IDLE
        if self._view is not None and self._view.descent is DescentStatus.REFUSED:
            return self._fail("the descent was refused (its motion line says why)", s, mode)
        if contact is ContactState.RETREATED and mode is Mode.RUNNING:
            return self._fail("contact anomaly: force-aware retreat", s, mode)
        timed_out = self._elapsed(s) > self.timing.insert_timeout_s
        if mode is Mode.DEGRADED and (contact is ContactState.RETREATED or timed_out):
            # The policy link was lost in contact and the card ended contact (retracted, or
            # a soft hold that has now waited out the insertion's time): give the cycle up.
            return self._fail("policy link lost in contact", s, mode)
        if contact is ContactState.DONE or timed_out:
            return self._request(P.VERIFY, s, mode)
        return None

    def _verify(self, s: Sensed, phase: TaskPhase, mode: Mode) -> PhaseRequest | None:
        if phase is P.RETREAT:
            self._enter(AssemblyStep.RELEASE, s.t_ns)
            self._requests.append(GripperRequest(self.layout.gripper_open))
            return None
        if self.outcome is None:
            truth = self.ground_truth() if self.ground_truth is not None else None
            verdict: InsertionVerdict = self.evaluator.verdict(self.insertion_evidence(s), truth)
            self.outcome = Outcome(verdict.verified, verdict.depth_m, verdict.reason)
        return self._request(P.RETREAT, s, mode)

    def _release(self, s: Sensed, phase: TaskPhase, mode: Mode) -> None:
        if self._elapsed(s) < self.timing.release_s:
            return
        tcp = self.planner.kin.forward(s.q).position
        lift = np.array([tcp[0], tcp[1], self.layout.staging_tcp[2]])
        try:
            self._plan(AssemblyStep.RETREAT_LIFT, s, lift)
        except PlanningError as error:
            # Wherever a failed approach left the arm (a policy may leave it anywhere), the
            # tool-down lift may have no IK solution: go home in joint space (the core checks
            # that move's clearance like any other) and keep the reason.
            self._failure = self._failure or f"no retreat lift: {error}"
            self._move_to(AssemblyStep.RETREAT_HOME, s, self.layout.home_q)

    def _after_retreat_lift(self, s: Sensed, phase: TaskPhase, mode: Mode) -> None:
        self._move_to(AssemblyStep.RETREAT_HOME, s, self.layout.home_q)

    def _after_retreat_home(self, s: Sensed, phase: TaskPhase, mode: Mode) -> PhaseRequest | None:
        if phase is P.IDLE:
            self._move_target = None
            if self.outcome is None:
                self.outcome = Outcome(False, self._depth_m, self._failure or "no verdict")
            self._enter(AssemblyStep.DONE, s.t_ns)
            return None
        return self._request(P.IDLE, s, mode)

    # -- evidence ----------------------------------------------------------------------------

    def insertion_evidence(self, s: Sensed) -> InsertionEvidence:
        """Where the measured tool is against the hole, and the force felt on the way in."""
        tcp = self.planner.kin.forward(s.q).position
        lateral = float(np.linalg.norm(tcp[:2] - self.layout.hole_top[:2]))
        self._depth_m = self.layout.insertion_depth_of(float(tcp[2]))
        return InsertionEvidence(self._depth_m, lateral, self._peak_force_n)

    def contact_evidence(self, s: Sensed) -> dict[str, bool]:
        """What the PRE_CONTACT → CONTACT guard needs, measured, never assumed."""
        pose = self.planner.kin.forward(s.q)
        goal = self.layout.pre_insert_tcp
        lateral = float(np.linalg.norm(pose.position[:2] - goal[:2]))
        height = abs(float(pose.position[2] - goal[2]))
        cos = (np.trace(pose.rotation.T @ self.layout.tool_down) - 1.0) / 2.0
        rotation = float(np.arccos(np.clip(cos, -1.0, 1.0)))
        t = self.timing
        margin = self.layout.workspace_margin
        inside = bool(np.all(np.abs(pose.position - goal) <= margin))
        return {
            "pose_within_tolerance": lateral <= t.pose_tolerance_m
            and height <= t.pose_height_tolerance_m and rotation <= t.rotation_tolerance_rad,
            "controller_mode_ack": s.driver_ok,
            "force_fresh": s.fresh,
            "contact_envelope_valid": inside and s.force_norm < t.envelope_force_n,
        }

    # -- helpers -----------------------------------------------------------------------------

    def _plan(self, step: AssemblyStep, s: Sensed, tcp: np.ndarray) -> None:
        """Ask for a classical move that ends with the tool down at ``tcp``.

        Raises:
            PlanningError: no IK solution for ``tcp`` (a layout the arm cannot reach).
        """
        self._move_to(step, s, self.planner.solve(s.q, tcp))

    def _move_to(self, step: AssemblyStep, s: Sensed, target: np.ndarray) -> None:
        self._moves += 1
        self._move_target = np.asarray(target, dtype=float)
        self._requests.append(MoveRequest(self._moves, self._move_target))
        self._enter(step, s.t_ns)

    def _enter(self, step: AssemblyStep, t_ns: int) -> None:
        self.step, self._since_ns = step, t_ns

    def _elapsed(self, s: Sensed) -> float:
        return (s.t_ns - self._since_ns) * 1e-9

    def _at_rest(self, s: Sensed) -> bool:
        return float(np.abs(s.qd).max()) <= self.timing.at_rest_rad_s

    def _request(self, to: TaskPhase, s: Sensed, mode: Mode,
                 evidence: dict[str, bool] | None = None) -> PhaseRequest | None:
        """Ask for ``to`` while the runtime is RUNNING, at most every request interval.

        Without the policy link (DEGRADED) the classical owners keep their jobs, so the way
        out of a cycle (retreat, then idle) is still asked for; nothing that needs the policy
        is."""
        if mode is not Mode.RUNNING and not (mode is Mode.DEGRADED and to in _WITHOUT_POLICY):
            return None
        if s.t_ns - self._last_request_ns < self.timing.request_interval_s * 1e9:
            return None
        self._last_request_ns = s.t_ns
        return PhaseRequest(to, evidence or {})

    def _fail(self, reason: str, s: Sensed, mode: Mode) -> PhaseRequest | None:
        """Give the cycle up: retreat, release the peg, go home, report why."""
        self._failure = reason
        self.outcome = Outcome(False, self._depth_m, reason)
        self._enter(AssemblyStep.VERIFY, s.t_ns)
        return self._request(P.RETREAT, s, mode)


_WITHOUT_POLICY = frozenset({P.RETREAT, P.IDLE})
"""Phases the cycle may still ask for in DEGRADED: the planner retreats, nothing is learned."""

_HANDLERS: dict[AssemblyStep, Callable[..., PhaseRequest | None]] = {
    AssemblyStep.START: AssemblyRunner._start,
    AssemblyStep.GRASP: AssemblyRunner._grasp,
    AssemblyStep.APPROACH: AssemblyRunner._approach,
    AssemblyStep.INSERT: AssemblyRunner._insert,
    AssemblyStep.VERIFY: AssemblyRunner._verify,
    AssemblyStep.RELEASE: AssemblyRunner._release,
}
_AFTER_MOVE: dict[AssemblyStep, Callable[..., PhaseRequest | None]] = {
    AssemblyStep.PICK_APPROACH: AssemblyRunner._after_pick_approach,
    AssemblyStep.PICK_DESCEND: AssemblyRunner._after_pick_descend,
    AssemblyStep.LIFT: AssemblyRunner._after_lift,
    AssemblyStep.TRANSPORT: AssemblyRunner._after_transport,
    AssemblyStep.RETREAT_LIFT: AssemblyRunner._after_retreat_lift,
    AssemblyStep.RETREAT_HOME: AssemblyRunner._after_retreat_home,
}
