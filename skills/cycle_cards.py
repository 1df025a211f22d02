"""The tabletop assembly cycle's phase contract cards, as data.

One card per step: who proposes, who approves, who executes, what must be fresh, and what
happens when it fails. The cell's task phases are coarser than the steps: acquire, grasp and
transport all run in FREE_SPACE.
"""

from __future__ import annotations

from dataclasses import dataclass

from skills.phases import TaskPhase


@dataclass(frozen=True, slots=True)
class StepCard:
    step: str
    phase: TaskPhase
    proposal_owner: str
    approval_owner: str
    execution_owner: str
    freshness: str
    fallback: str


CYCLE_CARDS: tuple[StepCard, ...] = (
    StepCard("acquire", TaskPhase.FREE_SPACE, "perception", "task FSM", "camera pipeline",
             "observation age", "reacquire or inspect"),
    StepCard("grasp", TaskPhase.FREE_SPACE, "scripted grasp pose", "IK/gripper gate",
             "trajectory and gripper", "pose and scene version", "scripted pose or abort"),
    StepCard("transport", TaskPhase.FREE_SPACE, "planner", "planning-scene validator",
             "trajectory controller", "scene/state stamp", "replan or hold"),
    StepCard("pre-contact", TaskPhase.PRE_CONTACT, "learned chunks (policy server)",
             "workspace/rate/phase gate (admission)", "setpoint interpolator",
             "short action-age bound", "staging-pose retreat"),
    StepCard("insert", TaskPhase.CONTACT, "bounded target only", "force/contact guard",
             "impedance law", "force/state freshness", "contact fallback"),
    StepCard("verify", TaskPhase.VERIFY, "independent evaluator", "task FSM",
             "no motion", "sensor confidence", "retry or inspect"),
    StepCard("retreat", TaskPhase.RETREAT, "classical trajectory", "collision/safety",
             "trajectory controller", "current scene", "stop or human recovery"),
)
