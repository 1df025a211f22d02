"""What the safety monitor's space check costs per sample, against its 4 ms check period.

``python bench/monitor_space.py [--samples N]``: the simulated cell's solids (the table, the
fixture some phase may touch, a keep-out box beside the arm) checked by
kernel/safety/space.py for measured configurations far from everything, near the table
(inside the clearance) and inside the keep-out box; beside it, in the same run, the joint,
speed and force comparisons every sample already gets (kernel/safety/checks.py). Prints
p50/p99/max in microseconds and the p99 as a share of the check period.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

if __package__ in (None, ""):  # run as a script: the repository's packages before bench/'s
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from kernel.cell_geometry import geometry_table
from kernel.model_file import BUILTIN
from kernel.safety.checks import Limits, Sample, breaches
from kernel.safety.settings import SafetySettings
from kernel.safety.space import SpaceCheck
from kernel.scenario.fields import Where

CELL = """
[geometry]
margin_m = 0.01
[[geometry.obstacles]]
name = "table"
shape = "box"
size = [0.6, 0.6, 0.025]
position = [-0.35, 0.0, -0.025]
[[geometry.obstacles]]
name = "fixture"
shape = "box"
size = [0.026, 0.026, 0.015]
position = [-0.55, -0.15, 0.015]
allow_contact = ["CONTACT"]
[[geometry.keep_out]]
name = "operator_bench"
shape = "box"
size = [0.3, 0.5, 1.0]
position = [0.2, 0.9, 1.0]
"""
HOME = (0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)
NEAR_TABLE = (0.0, -math.pi / 2, 2.85, -math.pi / 2 - (-math.pi / 2) - 2.85, -math.pi / 2, 0.0)
"""Tool down, the pads' tips a few millimetres above the table: inside the clearance."""
IN_BENCH = (-2.0, -0.6, 0.3, -1.0, -1.57, 0.0)
"""The arm swung towards the keep-out box."""


def _timed(check: Callable[[], object], samples: int) -> np.ndarray:
    times = np.empty(samples)
    for i in range(samples):
        started = time.perf_counter_ns()
        check()
        times[i] = time.perf_counter_ns() - started
    return times / 1e3


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=20_000)
    args = parser.parse_args(argv)
    geometry = geometry_table(tomllib.loads(CELL), Where("bench", ""))
    assert geometry is not None
    space = SpaceCheck(BUILTIN["ur5e"], 6, geometry)
    settings = SafetySettings(max_wrist_force_n=150.0)
    period_us = settings.check_period_ms * 1e3
    limits = Limits((-6.3,) * 6, (6.3,) * 6, (3.2,) * 6, 150.0, 0.02, 0.1)
    rows = [("joint, speed and force checks (baseline)",
             lambda: breaches(Sample(HOME, (0.0,) * 6, 10.0), limits), None)]
    for name, q in (("space, arm far from every solid", HOME),
                    ("space, pads inside the table's clearance", NEAR_TABLE),
                    ("space, arm inside the keep-out box", IN_BENCH)):
        rows.append((name, lambda q=q: space.findings(q), space.findings(q)))
    print(f"{len(space.solids)} solids checked ({', '.join(space.solids)}), "
          f"{space.model.ngeom - len(space.solids)} arm geoms; {args.samples} samples each; "
          f"check period {period_us:.0f} us")
    for name, check, found in rows:
        for _ in range(200):
            check()  # warm up
        times = _timed(check, args.samples)
        p50, p99, top = np.percentile(times, 50), np.percentile(times, 99), times.max()
        print(f"{name:<44} p50 {p50:7.1f} us  p99 {p99:7.1f} us  max {top:8.1f} us  "
              f"p99 = {100 * p99 / period_us:4.1f} % of the period"
              + (f"  [{len(found)} finding(s)]" if found is not None else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
