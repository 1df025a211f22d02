"""Scenarios for the cell's geometry: chunks inside every joint limit that would still hit the
table, the fixture or the arm itself are refused (COLLISION), and the decision line names the
pair. The cell is the shipped one (manifests/sim-ur5e.toml's [geometry]); the configurations
were solved with the arm's model (manifests/models/ur5e.xml) and are written out here."""

from __future__ import annotations

import math
from typing import Any

from tools.scenarios.base import ScenarioSpec, chunk, event, observation, robot, session
from tools.scenarios.base import state as st

GEOMETRY: dict[str, Any] = {
    "margin_m": 0.01,
    "self_collision": True,
    "phase_margin_m": {"PRE_CONTACT": 0.002, "CONTACT": 0.0, "VERIFY": 0.0, "RETREAT": 0.002},
    "part": {"shape": "box", "size": [0.01, 0.01, 0.03], "position": [0.0, 0.0, 0.0175]},
    "obstacles": [
        {"name": "table", "shape": "box", "size": [0.6, 0.6, 0.025],
         "position": [-0.35, 0.0, -0.025], "allow_contact": ["FREE_SPACE"]},
        {"name": "fixture", "shape": "box", "size": [0.02575, 0.02575, 0.015],
         "position": [-0.55, -0.15, 0.015], "allow_contact": ["CONTACT", "VERIFY", "RETREAT"]},
    ],
}
"""The shipped cell's [geometry] (tests/geometry/test_scenarios_geometry.py keeps them equal)."""

# TCP 10 cm above a point 15 cm from the fixture, tool down; then 2 cm below the table top.
TABLE_START = [0.0414, -1.6102, 2.2137, -2.1743, -1.5708, 0.0414]
TABLE_END = [0.0414, -1.3408, 2.3487, -2.5788, -1.5708, 0.0414]
# The held peg's bottom 2 cm above the fixture's top, 5 mm off the hole's centre; then 1 cm in.
FIXTURE_START = [0.0305, -1.2904, 1.8518, -2.1322, -1.5708, 0.0305]
FIXTURE_END = [0.0305, -1.2487, 1.8865, -2.2086, -1.5708, 0.0305]
# The shoulder lowered until the upper arm is 17 mm inside the table; the TCP stays 47 cm up.
ELBOW_START = [0.0, 0.0, -2.6, -1.0, -1.5708, 0.0]
ELBOW_END = [0.0, 0.3, -2.6, -1.0, -1.5708, 0.0]
# The elbow folded; wrist 1 turns the tool into the shoulder and upper arm, above the table.
WRIST_START = [0.0, -2.0, 2.4, -1.4, -1.5708, 0.0]
WRIST_END = [0.0, -2.0, 2.4, -0.8, -1.5708, 0.0]

STEPS = 40
"""Actions of 10 ms: a rest-to-rest cosine profile, inside every velocity and acceleration
limit of the scenario's robot."""


def _robot() -> dict[str, Any]:
    return {**robot(), "kinematics": "ur5e"}


def _profile(start: list[float], end: list[float], steps: int = STEPS) -> list[list[float]]:
    rows = []
    for j in range(1, steps + 1):
        s = 0.5 * (1.0 - math.cos(math.pi * j / steps))
        rows.append([round(a + s * (b - a), 6) for a, b in zip(start, end, strict=True)])
    return rows


def _refused(name: str, description: str, start: list[float], end: list[float],
             pair: list[str], held: bool = True) -> ScenarioSpec:
    events = [st(0, list(start)), observation(0, "O1"),
              chunk(20, "C1", 1, "O1", 0, first=20, actions=_profile(start, end),
                    state_fingerprint={"q": list(start), "hash": ""})]
    if held:
        events.insert(0, event(0, "gripper", opening=0.0))
    return ScenarioSpec(
        name=name, description=description, robot=_robot(), geometry=GEOMETRY,
        session=session(state=list(start)), events=events, until=60,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "rejected",
                 "reasons": ["COLLISION"], "collision.pair": pair, "t": 20},
                {"kind": "transition", "machine": "fallback", "to": "SAFE_HOLD",
                 "trigger": "COLLISION", "t": 20}],
        forbid=[{"kind": "tick", "sent.chunk_id": "C1"}],
    )


def collision_into_the_table() -> ScenarioSpec:
    return _refused(
        "collision_into_the_table",
        "A smooth joint-space approach inside every joint, velocity and acceleration limit, to "
        "a pose whose TCP is 2 cm below the table top, 15 cm from the fixture, with the peg "
        "held: the held part would enter the table, so the chunk is refused (COLLISION, the "
        "pair and its distance on the line) and the arm holds (SAFE_HOLD).",
        TABLE_START, TABLE_END, ["part", "table"])


def collision_into_the_fixture() -> ScenarioSpec:
    return _refused(
        "collision_into_the_fixture",
        "The held peg driven 1 cm down into the fixture's top beside the hole in PRE_CONTACT "
        "(the fixture may be touched only in CONTACT and VERIFY): COLLISION before any of it "
        "runs.",
        FIXTURE_START, FIXTURE_END, ["part", "fixture"])


def collision_elbow_into_the_table() -> ScenarioSpec:
    return _refused(
        "collision_elbow_into_the_table",
        "The shoulder lowered until the upper arm would dip into the table while the TCP stays "
        "47 cm above it: the links keep their clearance too, whatever the tool does.",
        ELBOW_START, ELBOW_END, ["upper_arm_linkGeom_0", "table"], held=False)


def collision_wrist_into_the_upper_arm() -> ScenarioSpec:
    return _refused(
        "collision_wrist_into_the_upper_arm",
        "With the elbow folded, wrist 1 turns the tool into the shoulder and the upper arm, far "
        "from the table: two links that are not neighbours keep their clearance "
        "(self-collision); the finger pad meets the shoulder first.",
        WRIST_START, WRIST_END, ["shoulder_linkGeom_1", "pad_left"], held=False)


def collision_free_approach_admitted() -> ScenarioSpec:
    high = [0.0414, -1.7316, 2.0356, -1.8748, -1.5708, 0.0414]  # TCP 20 cm up
    events = [event(0, "gripper", opening=0.0), st(0, list(high)), observation(0, "O1"),
              chunk(20, "C1", 1, "O1", 0, first=20, actions=_profile(high, TABLE_START),
                    state_fingerprint={"q": list(high), "hash": ""})]
    return ScenarioSpec(
        name="collision_free_approach_admitted",
        description="The into-the-table approach's first half, from 20 cm down to 10 cm above "
                    "the table with the peg held: every action and the motion between them "
                    "keep the clearance, so the chunk is admitted and runs.",
        robot=_robot(), geometry=GEOMETRY, session=session(state=list(high)),
        events=events, until=100,
        expect=[{"kind": "chunk", "chunk_id": "C1", "decision": "accepted", "t": 20},
                {"kind": "tick", "t": 20, "sent.chunk_id": "C1", "owner": "policy"}],
        forbid=[{"kind": "chunk", "reasons": ["COLLISION"]}],
    )


def collision_planner_move_refused() -> ScenarioSpec:
    """The planner's own moves are checked the same way, before the first step plays."""
    planner = {"FREE_SPACE": {"executor": "planner"}}
    return ScenarioSpec(
        name="collision_planner_move_refused",
        description="A classical move the task asks for in FREE_SPACE (the planner owns "
                    "motion) would lower the upper arm into the table: its clearance is "
                    "checked once it is planned, before it plays; it is refused naming the "
                    "pair, and the arm stays at rest. The move back up is planned and played.",
        robot=_robot(), geometry=GEOMETRY, phases=planner,
        session=session(phase="FREE_SPACE", state=list(ELBOW_START)),
        events=[st(0, list(ELBOW_START)),
                event(10, "move", move_id=1, target=list(ELBOW_END)),
                event(40, "move", move_id=2, target=[0.0, -0.2, -2.6, -1.0, -1.5708, 0.0])],
        until=60,
        expect=[{"kind": "motion", "request": "move", "decision": "refused", "move_id": 1},
                {"kind": "motion", "request": "move", "decision": "planned", "move_id": 2},
                {"kind": "tick", "t": 38, "owner": "planner", "phase": "FREE_SPACE"}],
        forbid=[{"kind": "motion", "decision": "planned", "move_id": 1}],
    )


TOOL_DOWN = [0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0]
"""The TCP's rotation at FIXTURE_START (row-major): the tool's axis straight down."""
HOLE_XY = [-0.55, -0.15]
PEG_BOTTOM_BELOW_TCP = 0.0475


def collision_descent_refused() -> ScenarioSpec:
    """The contact owner's descent is checked before it starts, at CONTACT's clearance."""
    contact = {"CONTACT": {"executor": "contact"}}
    return ScenarioSpec(
        name="collision_descent_refused",
        description="In CONTACT the task asks the contact owner for a descent into the hole "
                    "whose end would put the held peg's bottom 5 mm into the table under the "
                    "fixture: the tool and the part may touch the fixture in CONTACT, not the "
                    "table. The descent's path is checked before it starts and refused naming "
                    "the pair, the contact owner holding where the arm is; the next insert, to "
                    "3 mm above the table, is cleared and starts.",
        robot=_robot(), geometry=GEOMETRY, phases=contact,
        session=session(phase="CONTACT", state=list(FIXTURE_START)),
        events=[event(0, "gripper", opening=0.0), st(0, list(FIXTURE_START)),
                event(10, "insert", xy=HOLE_XY, z_end=PEG_BOTTOM_BELOW_TCP - 0.005,
                      rotation=TOOL_DOWN),
                event(30, "insert", xy=HOLE_XY, z_end=PEG_BOTTOM_BELOW_TCP + 0.003,
                      rotation=TOOL_DOWN)],
        until=60,
        expect=[{"kind": "motion", "request": "insert", "decision": "refused", "t": 10},
                {"kind": "motion", "request": "insert", "decision": "started", "t": 30},
                {"kind": "tick", "t": 20, "owner": "contact", "phase": "CONTACT"}],
        forbid=[{"kind": "motion", "request": "insert", "decision": "started", "t": 10}],
    )


SCENARIOS = (collision_into_the_table, collision_into_the_fixture,
             collision_elbow_into_the_table, collision_wrist_into_the_upper_arm,
             collision_free_approach_admitted, collision_planner_move_refused,
             collision_descent_refused)
