"""Whole cells on the wall clock, side by side in one run: deadline misses and time to target.

    python bench/cells.py [--cycles N] [--root DIR] [MANIFEST ...]

Each manifest runs as ``warden run MANIFEST --cycles N`` in its own process (the command line
is the stable interface, so ``--root`` can point at another checkout of warden to measure it on
the same machine in the same run). Printed per cell: control period, ticks, deadline misses
(later than half a period, or skipped), p99 lateness, and the approach time: from entering
PRE_CONTACT to entering CONTACT, per cycle (the policy's stream through the setpoint
interpolator, so a cell whose interpolator ran on the wrong period shows it here).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ("sim-ur5e.toml", "sim-ur5e-cartesian.toml", "sim-dynamixel.toml",
           "sim-canopen.toml")


def run_cell(root: Path, manifest: str, cycles: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as journals:
        command = [sys.executable, "-m", "kernel.cli", "run", str(root / "manifests" / manifest),
                   "--cycles", str(cycles), "--journal-dir", journals, "--json", "-",
                   "--log-format", "json"]
        env = {**os.environ, "PYTHONPATH": str(root)}
        done = subprocess.run(command, cwd=root, env=env, capture_output=True, text=True,
                              timeout=120 + 60 * cycles, check=False)
        if not done.stdout.strip().startswith("{"):
            raise RuntimeError(f"{manifest}: no summary (exit {done.returncode}):\n"
                               f"{done.stderr[-2000:]}")
        summary = json.loads(done.stdout)
        decisions = next(Path(journals).glob("*/decisions.jsonl"))
        summary["approach_s"] = _approaches(decisions)
    return summary


def _approaches(decisions: Path) -> list[float]:
    """Seconds from each entry into PRE_CONTACT to the next entry into CONTACT."""
    started, spans = None, []
    for raw in decisions.open():
        line = json.loads(raw)
        if line.get("kind") != "transition" or line.get("machine") != "task":
            continue
        if line.get("accepted", True) and line["to"] == "PRE_CONTACT":
            started = line["t"]
        elif line.get("accepted", True) and line["to"] == "CONTACT" and started is not None:
            spans.append(round((line["t"] - started) / 1000.0, 3))
            started = None
    return spans


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("manifests", nargs="*", default=list(DEFAULT))
    parser.add_argument("--cycles", type=int, default=2)
    parser.add_argument("--root", type=Path, default=ROOT,
                        help="the warden checkout to run (default: this one)")
    args = parser.parse_args()
    print(f"cells at {args.root}, {args.cycles} cycle(s) each")
    print(f"{'manifest':<26} {'period':>6} {'ticks':>6} {'misses':>7} {'rate':>7} "
          f"{'p99 us':>7} {'verified':>8}  approach s")
    for manifest in args.manifests:
        summary = run_cell(args.root, manifest, args.cycles)
        loop = summary["loop"]
        lateness = loop.get("lateness_us") or {}
        cycles = summary["cycles"]
        print(f"{manifest:<26} {_period(args.root, manifest):>6} {loop['ticks']:>6} "
              f"{loop['misses']:>7} {100 * loop['miss_rate']:>6.2f}% "
              f"{lateness.get('p99', float('nan')):>7.0f} "
              f"{cycles['verified']:>3}/{cycles['attempted']:<4}  {summary['approach_s']}")


def _period(root: Path, manifest: str) -> str:
    for line in (root / "manifests" / manifest).read_text().splitlines():
        if line.strip().startswith("control_period_ms"):
            return line.split("=")[1].split("#")[0].strip() + " ms"
    return "?"


if __name__ == "__main__":
    main()
