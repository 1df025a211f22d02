"""VERIFY's evaluator: measured evidence decides; a simulator's ground truth must agree."""

from __future__ import annotations

import math

import pytest

from skills.evaluator import Evaluator, InsertionEvidence

EVALUATOR = Evaluator(tolerance_m=0.015, lateral_tolerance_m=0.002, max_force_n=25.0)
GOOD = InsertionEvidence(depth_m=0.027, lateral_m=0.0004, peak_force_n=12.0)


def test_measured_evidence_alone_verifies_a_clean_insertion() -> None:
    verdict = EVALUATOR.verdict(GOOD)
    assert verdict.verified and verdict.depth_m == GOOD.depth_m
    assert "ground truth" not in verdict.reason


@pytest.mark.parametrize(("evidence", "says"), [
    (InsertionEvidence(0.014, 0.0004, 12.0), "deep"),
    (InsertionEvidence(0.027, 0.0021, 12.0), "off the hole's axis"),
    (InsertionEvidence(0.027, 0.0004, 25.5), "force"),
    (InsertionEvidence(math.nan, 0.0004, 12.0), "no measured evidence"),
], ids=["shallow", "beside-the-hole", "forced", "not-measured"])
def test_each_measured_bound_fails_the_cycle_and_says_which(
        evidence: InsertionEvidence, says: str) -> None:
    verdict = EVALUATOR.verdict(evidence, ground_truth_m=0.027)
    assert not verdict.verified and says in verdict.reason


def test_ground_truth_is_an_extra_check_that_must_agree() -> None:
    assert EVALUATOR.verdict(GOOD, ground_truth_m=0.027).verified
    disagreed = EVALUATOR.verdict(GOOD, ground_truth_m=0.002)
    assert not disagreed.verified and "disagree" in disagreed.reason
    assert not EVALUATOR.verdict(GOOD, ground_truth_m=math.nan).verified


def test_no_evidence_is_no_verdict() -> None:
    assert not EVALUATOR.verdict(None, ground_truth_m=0.027).verified
