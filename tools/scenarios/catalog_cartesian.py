"""Scenarios for Cartesian proposals: TCP displacements mapped through IK, then admitted."""

from __future__ import annotations

from typing import Any

from tools.scenarios.base import Q0, ScenarioSpec, chunk, observation, robot, session
from tools.scenarios.base import state as st

# The TCP at Q0 is at about (-0.628, -0.134, 0.178) m; the box leaves a few centimetres around.
WORKSPACE = {"lower": [-0.70, -0.20, 0.15], "upper": [-0.55, -0.05, 0.25]}


def _robot() -> dict[str, Any]:
    return {**robot(), "kinematics": "ur5e", "workspace": WORKSPACE}


def _session() -> dict[str, Any]:
    return {**session(), "action_dim": 3, "action_units": "m", "action_frame": "base_delta"}


def _cartesian(t: float, chunk_id: str, sequence: int, deltas: list[list[float]],
               **fields: Any) -> dict[str, Any]:
    return chunk(t, chunk_id, sequence, "O1", 0, first=t, actions=deltas,
                 action_frame="base_delta", action_units="m",
                 state_fingerprint={"q": list(Q0), "hash": ""}, **fields)


def _descent(step_m: float, count: int) -> list[list[float]]:
    return [[0.0, 0.0, -step_m * k] for k in range(1, count + 1)]


def cartesian_delta_admitted() -> ScenarioSpec:
    return ScenarioSpec(
        name="cartesian_delta_admitted",
        description="A Cartesian session: each action moves the TCP from the pose the policy "
                    "observed (here 0.5 mm steps down). The chunk is mapped through IK to joint "
                    "targets, which pass the same divergence and feasibility gates and run.",
        robot=_robot(), session=_session(),
        events=[st(0, list(Q0)), observation(0, "O1"),
                _cartesian(20, "C1", 1, _descent(0.0005, 8))],
        until=100,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "accepted", "t": 20},
                {"kind": "tick", "t": 20, "sent.chunk_id": "C1", "owner": "policy"},
                {"kind": "tick", "t": 90, "sent.chunk_id": "C1"}],
    )


def cartesian_outside_workspace() -> ScenarioSpec:
    return ScenarioSpec(
        name="cartesian_outside_workspace",
        description="A Cartesian chunk whose TCP would leave the workspace box is INFEASIBLE as "
                    "a whole (the detail names the action and the position); nothing of it "
                    "runs and the planner takes over (REPLAN_OR_RETREAT).",
        robot=_robot(), session=_session(),
        events=[st(0, list(Q0)), observation(0, "O1"),
                _cartesian(20, "C1", 1, _descent(0.01, 6))],
        until=40,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
                 "reasons": ["INFEASIBLE"], "t": 20},
                {"kind": "transition", "machine": "fallback", "to": "REPLAN_OR_RETREAT",
                 "trigger": "INFEASIBLE", "t": 20}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


def cartesian_unreachable() -> ScenarioSpec:
    session_doc = _session()
    return ScenarioSpec(
        name="cartesian_unreachable",
        description="Without a workspace box, a Cartesian target out of the arm's reach has no "
                    "IK solution: INFEASIBLE, with the action named in the detail.",
        robot={**robot(), "kinematics": "ur5e"}, session=session_doc,
        events=[st(0, list(Q0)), observation(0, "O1"),
                _cartesian(20, "C1", 1, [[0.0, 0.0, -0.0005], [2.0, 0.0, 0.0]])],
        until=30,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
                 "reasons": ["INFEASIBLE"], "t": 20}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


def joint_chunk_in_cartesian_session() -> ScenarioSpec:
    return ScenarioSpec(
        name="joint_chunk_in_cartesian_session",
        description="A joint-space chunk sent into a Cartesian session does not match the "
                    "agreed schema (SCHEMA_MISMATCH) and is never mapped or run.",
        robot=_robot(), session=_session(),
        events=[st(0, list(Q0)), observation(0, "O1"),
                chunk(20, "C1", 1, "O1", 0, first=20, actions=[list(Q0)] * 3,
                      action_frame="joint", action_units="rad")],
        until=30,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
                 "reasons_include": ["SCHEMA_MISMATCH"], "t": 20}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


SCENARIOS = [cartesian_delta_admitted, cartesian_outside_workspace, cartesian_unreachable,
             joint_chunk_in_cartesian_session]
