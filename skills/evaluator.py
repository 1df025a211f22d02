"""The evaluator of VERIFY: did the part go in? Judged on measured evidence.

What any cell can measure decides: where the tool is at the end of the insertion (from the
arm's measured joints through its kinematic model) against where the fixture's hole is, and
the force the wrist sensor felt on the way down. A simulation can add its ground truth (the
part's true depth) as an extra check: a verdict is positive only if both agree, and a
disagreement is named, so a runtime that fools itself cannot pass, and neither can an
evaluator that trusts the simulator more than the measurements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class InsertionEvidence:
    """What was measured at the end of an insertion."""

    depth_m: float
    """How deep the held part's bottom is below the fixture's top face, from the measured TCP
    height and the grasp geometry."""
    lateral_m: float
    """How far the measured TCP is from the hole's axis."""
    peak_force_n: float
    """The largest wrist force measured during the insertion."""


@dataclass(frozen=True, slots=True)
class InsertionVerdict:
    verified: bool
    depth_m: float
    reason: str


@dataclass(frozen=True, slots=True)
class Evaluator:
    tolerance_m: float
    """Depth below the fixture's top face that counts as inserted."""
    lateral_tolerance_m: float = 0.002
    """The TCP must be this close to the hole's axis: deep and this close, the part is in the
    hole (the fixture's top is solid everywhere else)."""
    max_force_n: float = 25.0
    """An insertion that needed more force than this is not a clean one."""

    def verdict(self, evidence: InsertionEvidence | None,
                ground_truth_m: float | None = None) -> InsertionVerdict:
        """The verdict on ``evidence``; ``ground_truth_m`` (a simulator's) must agree."""
        if evidence is None or not all(map(math.isfinite, (
                evidence.depth_m, evidence.lateral_m, evidence.peak_force_n))):
            return InsertionVerdict(False, 0.0, "no measured evidence of the insertion")
        failure = self._measured_failure(evidence)
        if failure:
            return InsertionVerdict(False, evidence.depth_m, failure)
        if ground_truth_m is not None and not ground_truth_m >= self.tolerance_m:
            return InsertionVerdict(False, evidence.depth_m, (
                f"measured {_mm(evidence.depth_m)} deep, but the simulator's ground truth "
                f"says {_mm(ground_truth_m)}: they disagree"))
        truth = "" if ground_truth_m is None else f", ground truth {_mm(ground_truth_m)}"
        return InsertionVerdict(True, evidence.depth_m,
                                f"inserted: measured {_mm(evidence.depth_m)}{truth}")

    def _measured_failure(self, evidence: InsertionEvidence) -> str:
        if evidence.depth_m < self.tolerance_m:
            return (f"part {_mm(evidence.depth_m)} deep (measured), needs "
                    f"{_mm(self.tolerance_m)}")
        if evidence.lateral_m > self.lateral_tolerance_m:
            return (f"tool {_mm(evidence.lateral_m)} off the hole's axis (measured), allowed "
                    f"{_mm(self.lateral_tolerance_m)}")
        if evidence.peak_force_n > self.max_force_n:
            return (f"insertion force reached {evidence.peak_force_n:.1f} N, allowed "
                    f"{self.max_force_n:.1f} N")
        return ""


def _mm(metres: float) -> str:
    return f"{metres * 1000:.1f} mm"
