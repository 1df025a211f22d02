"""Long steps: the motion between two far-apart actions (the first step out of a hold that the
queue ran dry into, a sparse chunk) is judged by halving it, never by the one bound over the
whole step alone, which would refuse every long step that passes near a solid it keeps clear
of. Judged by the same independent oracle as tests/geometry/test_clearance_oracle.py, sampled
finely enough for steps this long.
"""

from __future__ import annotations

import itertools

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.geometry.oracle import MujocoOracle
from tests.geometry.test_clearance_oracle import (
    ANCHORS,
    BAND,
    NEAR_TABLE,
    PHASE,
    SELF_BAND,
    STEP,
    TOLERANCE,
)
from tools.scenarios.catalog_collision import FIXTURE_END

LONG = 0.08
"""rad: the largest joint step of a long motion here (20 of the short chunks' steps)."""
SAMPLES = 80
"""Oracle samples per long step: one per 1 mrad of its longest joint's turn."""


def _oracle_slack(oracle: MujocoOracle, qs: np.ndarray) -> dict[str, float]:
    slack = {"self": np.inf, "world": np.inf}
    for a, b in itertools.pairwise(qs):
        for s in np.linspace(0.0, 1.0, SAMPLES + 1):
            for kind, (value, _) in oracle.slacks(a + s * (b - a), PHASE).items():
                slack[kind] = min(slack[kind], value)
    return slack


def test_a_long_step_along_the_table_is_admitted(checker, oracle) -> None:  # type: ignore[no-untyped-def]
    """The held peg 2 cm above the table swings 0.08 rad about the base in one step: about
    4 cm along the table top at the same height. The oracle finds the whole motion clear; the
    step's one bound, (d(a) + d(b) − s) / 2, is far under the clearance (its travel ``s`` is
    larger than both distances together), so only halving it can admit it."""
    start = np.array(NEAR_TABLE)
    end = start + np.array([LONG, 0.0, 0.0, 0.0, 0.0, 0.0])
    slack = _oracle_slack(oracle, np.vstack((start, end)))
    assert slack["world"] > BAND and slack["self"] > SELF_BAND, slack
    assert checker.check(start, end[None, :], PHASE, held=True) is None


def test_a_long_step_that_dips_between_its_ends_is_refused(checker, oracle) -> None:  # type: ignore[no-untyped-def]
    """Both ends keep the clearance, the middle of the motion does not: the peg, just under
    the fixture's top, swings 0.2 rad about the base in one step from one side of the fixture
    to the other, through it. Halving finds the configuration that breaks the clearance."""
    through = np.array(FIXTURE_END)
    swing = np.array([0.1, 0.0, 0.0, 0.0, 0.0, 0.0])
    start, end = through - swing, through + swing
    assert min(oracle.slack(q, PHASE)[0] for q in (start, end)) > 0.0
    assert oracle.slack(through, PHASE)[0] < -TOLERANCE
    found = checker.check(start, end[None, :], PHASE, held=True)
    assert found is not None and found.pair == ("part", "fixture"), found
    assert found.distance >= found.needed > found.bound


long_motions = st.tuples(
    st.sampled_from(range(len(ANCHORS))),
    st.lists(st.floats(-0.05, 0.05), min_size=6, max_size=6),
    st.lists(st.lists(st.floats(-LONG, LONG), min_size=6, max_size=6), min_size=1, max_size=2),
)
"""An anchor near a solid, an offset from it and one or two long steps."""


def _motion(drawn: tuple[int, list[float], list[list[float]]],
            ) -> tuple[np.ndarray, np.ndarray]:
    anchor, offset, steps = drawn
    start = np.array(ANCHORS[anchor]) + np.array(offset)
    return start, start + np.cumsum(np.array(steps), axis=0)


def _clear(slack: dict[str, float]) -> bool:
    return slack["world"] > BAND and slack["self"] > SELF_BAND


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(long_motions)
def test_long_steps_are_refused_iff_the_oracle_finds_the_clearance_broken(
        checker, oracle, drawn) -> None:  # type: ignore[no-untyped-def]
    start, rows = _motion(drawn)
    if not _clear(_oracle_slack(oracle, np.vstack((start, start)))):
        return  # a motion starts where the arm is, clear of everything
    verdict = checker.check(start, rows, PHASE, held=True)
    slack = _oracle_slack(oracle, np.vstack((start, rows)))
    if min(slack.values()) < -TOLERANCE:
        assert verdict is not None, f"oracle slack {slack} m, the core admitted it"
    if _clear(slack):
        assert verdict is None, f"oracle slack {slack} m, the core refused: {verdict}"


def test_the_long_motions_reach_both_verdicts(oracle) -> None:  # type: ignore[no-untyped-def]
    """The property above is not vacuous: its motions fall on both sides of the band."""
    rng = np.random.default_rng(18)
    below = above = 0
    for _ in range(60):
        drawn = (int(rng.integers(len(ANCHORS))), rng.uniform(-0.05, 0.05, 6).tolist(),
                 rng.uniform(-LONG, LONG, (2, 6)).tolist())
        start, rows = _motion(drawn)
        if not _clear(_oracle_slack(oracle, np.vstack((start, start)))):
            continue
        slack = _oracle_slack(oracle, np.vstack((start, rows)))
        below += min(slack.values()) < -TOLERANCE
        above += _clear(slack)
    assert below >= 3 and above >= 10, (below, above)


def test_halving_stops_at_its_budget(checker) -> None:  # type: ignore[no-untyped-def]
    """Sixty long steps along the table, each clear, cost at most the budget: the motions
    halving could not reach are refused (conservative), never admitted unchecked."""
    start = np.array(NEAR_TABLE)
    rows = start + np.arange(1, 61)[:, None] * np.array([LONG, 0, 0, 0, 0, 0]) / 8
    assert STEP < LONG / 8
    found = checker.check(start, rows, PHASE, held=True)
    assert found is None or found.distance >= found.needed
