"""The independent evaluator of VERIFY: did the peg go in?

It looks only at what a separate sensor would see (in simulation, the ground truth of the
plant), never at the runtime's own belief, so a runtime that fools itself cannot pass.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Verdict:
    verified: bool
    depth_m: float
    reason: str


@dataclass(frozen=True, slots=True)
class Evaluator:
    tolerance_m: float
    """Depth of the peg below the fixture's top face that counts as inserted."""

    def verdict(self, insertion_depth_m: float) -> Verdict:
        if insertion_depth_m != insertion_depth_m:  # NaN: nobody measured it
            return Verdict(False, 0.0, "no independent evaluator on this cell")
        if insertion_depth_m >= self.tolerance_m:
            return Verdict(True, insertion_depth_m, "inserted")
        return Verdict(False, insertion_depth_m,
                       f"peg {insertion_depth_m * 1000:.1f} mm deep, "
                       f"needs {self.tolerance_m * 1000:.1f} mm")
