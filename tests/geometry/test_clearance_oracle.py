"""The core's clearance check against an independent oracle: MuJoCo's own kinematics and
collision distances on the same scene (tests/geometry/oracle.py), never the core's coal queries.

Random chunks near the table, the fixture and the arm itself (the held peg in PRE_CONTACT):
- a chunk the oracle finds coming closer than the clearance, at an action or anywhere on the
  straight joint-space motion between two (sampled finely), is refused;
- a chunk the oracle finds keeping the clearance with ``BAND`` to spare against the world's
  solids and ``SELF_BAND`` between the arm's own links is admitted.
Between the two (a clearance slack from −``TOLERANCE`` to the band) either verdict is
accepted: the core's bound on the motion between actions is conservative by up to half the
distance its geometry could travel in one step (steps here are at most ``STEP`` rad per joint;
two links move relative to each other only by the joints between them, hence the narrower
band), and two collision libraries agree to a fraction of a millimetre, not to the bit.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.geometry.oracle import MujocoOracle
from tools.scenarios.catalog_collision import (
    ELBOW_END,
    ELBOW_START,
    FIXTURE_END,
    FIXTURE_START,
    GEOMETRY,
    TABLE_END,
    TABLE_START,
    WRIST_END,
    WRIST_START,
)

PHASE = "PRE_CONTACT"
TOLERANCE = 0.0005
"""m: how far the two libraries' distances may differ, and the oracle's fine sampling of a
motion may miss its closest point."""
BAND = 0.012
"""m: the widest margin by which the core's motion bound may be conservative here."""
SELF_BAND = 0.006
"""m: the same between two links of the arm."""
STEP = 0.004
"""rad: the largest joint step between two actions of a random chunk."""
SUBSAMPLES = 6
NEAR_TABLE = [0.0414, -1.5509, 2.2598, -2.2797, -1.5708, 0.0414]
"""The held peg's bottom 2 cm above the table."""
NEAR_ELBOW = [0.0, 0.2, -2.6, -1.0, -1.5708, 0.0]
"""The upper arm 24 mm above the table."""
HIGH = [0.0414, -1.7316, 2.0356, -1.8748, -1.5708, 0.0414]
"""The TCP 20 cm above the table, tool down."""
ANCHORS = [TABLE_START, NEAR_TABLE, FIXTURE_START, NEAR_ELBOW, WRIST_START]


chunks = st.tuples(
    st.sampled_from(range(len(ANCHORS))),
    st.lists(st.floats(-0.05, 0.05), min_size=6, max_size=6),
    st.lists(st.floats(-0.75 * STEP, 0.75 * STEP), min_size=6, max_size=6),
    st.lists(st.lists(st.floats(-0.25 * STEP, 0.25 * STEP), min_size=6, max_size=6),
             min_size=1, max_size=30),
)
"""An anchor, an offset from it, a drift per action and each action's own jitter."""


def _chunk(drawn: tuple[int, list[float], list[float], list[list[float]]],
           ) -> tuple[np.ndarray, np.ndarray]:
    anchor, offset, drift, jitter = drawn
    start = np.array(ANCHORS[anchor]) + np.array(offset)
    rows = start + np.cumsum(np.array(drift) + np.array(jitter), axis=0)
    return start, rows


def _oracle_slack(oracle: MujocoOracle, start: np.ndarray,
                  rows: np.ndarray) -> dict[str, float]:
    """The smallest clearance slack of the self and of the world pairs over every action and
    the motion into it."""
    qs = np.vstack((start, rows))
    slack = {"self": np.inf, "world": np.inf}
    for a, b in itertools.pairwise(qs):
        for s in np.linspace(0.0, 1.0, SUBSAMPLES + 1)[1:]:
            for kind, (value, _) in oracle.slacks(a + s * (b - a), PHASE).items():
                slack[kind] = min(slack[kind], value)
    return slack


def _clear(slack: dict[str, float]) -> bool:
    return slack["world"] > BAND and slack["self"] > SELF_BAND


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(chunks)
def test_refused_iff_the_oracle_finds_the_clearance_broken(checker, oracle, drawn) -> None:  # type: ignore[no-untyped-def]
    start, rows = _chunk(drawn)
    if not _clear(_oracle_slack(oracle, start, start[None, :])):
        return  # a chunk starts from where the arm is: a configuration that keeps its clearance
    verdict = checker.check(start, rows, PHASE, held=True)
    slack = _oracle_slack(oracle, start, rows)
    if min(slack.values()) < -TOLERANCE:
        assert verdict is not None, f"oracle slack {slack} m, the core admitted it"
    if _clear(slack):
        assert verdict is None, f"oracle slack {slack} m, the core refused: {verdict}"


def test_the_random_chunks_reach_both_verdicts(checker, oracle) -> None:  # type: ignore[no-untyped-def]
    """The property above is not vacuous: its chunks fall on both sides of the band."""
    rng = np.random.default_rng(17)
    below = above = 0
    for _ in range(100):
        drawn = (int(rng.integers(len(ANCHORS))), rng.uniform(-0.05, 0.05, 6).tolist(),
                 rng.uniform(-0.75 * STEP, 0.75 * STEP, 6).tolist(),
                 rng.uniform(-0.25 * STEP, 0.25 * STEP, (30, 6)).tolist())
        start, rows = _chunk(drawn)
        if not _clear(_oracle_slack(oracle, start, start[None, :])):
            continue
        slack = _oracle_slack(oracle, start, rows)
        below += min(slack.values()) < -TOLERANCE
        above += _clear(slack)
    assert below >= 3 and above >= 10, (below, above)


def test_the_oracle_and_the_core_agree_on_each_pair_at_a_configuration(
        checker, oracle) -> None:  # type: ignore[no-untyped-def]
    """At the scenarios' end poses the closest pair and its slack agree within tolerance."""
    for q in (TABLE_END, ELBOW_START, WRIST_START, NEAR_TABLE, NEAR_ELBOW):
        distances = checker.distances(np.array(q), PHASE, held=True)
        core = min(d - (GEOMETRY["margin_m"] if not ({"table", "fixture"} & set(pair)) else
                        GEOMETRY["phase_margin_m"][PHASE]) for pair, d in distances.items())
        assert abs(core - oracle.slack(np.array(q), PHASE)[0]) < TOLERANCE


SEGMENTS = {
    "part into the table": (NEAR_TABLE, TABLE_END),
    "part into the fixture": (FIXTURE_START, FIXTURE_END),
    "upper arm into the table": (NEAR_ELBOW, ELBOW_END),
    "tool into the shoulder": (WRIST_START, WRIST_END),
}


def _where_slack_is(oracle: MujocoOracle, start: np.ndarray, end: np.ndarray,
                    slack: float) -> np.ndarray:
    """The configuration on the segment where the oracle's slack first falls to ``slack``
    (bisection on the oracle alone)."""
    low, high = 0.0, 1.0
    for _ in range(40):
        middle = 0.5 * (low + high)
        if oracle.slack(start + middle * (end - start), PHASE)[0] > slack:
            low = middle
        else:
            high = middle
    return start + low * (end - start)


@pytest.mark.parametrize("name", SEGMENTS)
def test_the_verdict_flips_at_the_clearance(checker, oracle, name: str) -> None:  # type: ignore[no-untyped-def]
    """A motion that ends 1 mm inside a pair's clearance (by the oracle) is refused; the same
    motion ending ``BAND`` outside it is admitted."""
    start, end = (np.array(q) for q in SEGMENTS[name])
    for slack, refused in ((-0.001, True), (BAND + 0.001, False)):
        goal = _where_slack_is(oracle, start, end, slack)
        rows = start + np.linspace(0.0, 1.0, 61)[1:, None] * (goal - start)
        verdict = checker.check(start, rows, PHASE, held=True)
        assert (verdict is not None) is refused, (name, slack, verdict)


glances = st.tuples(
    st.sampled_from(range(len(ANCHORS))),
    st.lists(st.floats(-0.3, 0.3), min_size=6, max_size=6),
    st.lists(st.floats(-0.75 * STEP, 0.75 * STEP), min_size=6, max_size=6),
    st.lists(st.lists(st.floats(-0.25 * STEP, 0.25 * STEP), min_size=6, max_size=6),
             min_size=1, max_size=30),
)
"""As ``chunks``, from farther around the anchors: far enough from every solid for the one
distance query to prove some of them clear."""


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(glances)
def test_what_one_distance_query_clears_the_oracle_finds_clear(checker, oracle, drawn) -> None:  # type: ignore[no-untyped-def]
    """The shortcut that admission takes inline (one distance query at the start, then a
    bound on the whole path) never clears a motion that comes closer than the clearance."""
    start, rows = _chunk(drawn)
    if checker.clear_by_travel(start, rows, PHASE, held=True):
        slack = _oracle_slack(oracle, start, rows)
        assert min(slack.values()) >= -TOLERANCE, f"oracle slack {slack} m, cleared at a glance"


def test_one_distance_query_clears_chunks_away_from_the_solids(checker) -> None:  # type: ignore[no-untyped-def]
    """The shortcut is not vacuous: 100 ms of every joint turning at the reference policy's
    0.3 rad/s (10 actions of 10 ms) with the TCP 20 cm above the table is cleared by it, and
    the same chunk 2 cm above the table is not (the exact check decides that one)."""
    pace = np.full(6, 0.3 * 0.01)
    for anchor, cleared in ((HIGH, True), (NEAR_TABLE, False)):
        start = np.array(anchor)
        rows = start + np.arange(1, 11)[:, None] * pace
        assert checker.clear_by_travel(start, rows, PHASE, held=True) is cleared, anchor
