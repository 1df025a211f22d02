"""Every driver through ManagedDriver against its emulator: write + read cycle latency and the
highest sustainable control rate, side by side (issue 4). Figures are printed, never asserted.

    .venv/bin/python bench/drivers.py [--seconds 5]

Each driver's own benchmark (``bench/drivers_ur.py``, ``bench/drivers_dynamixel.py``,
``bench/drivers_canopen.py``) prints its per-rate details; this one runs all three and the
plant driver, whose cycle is the baseline: the same lifecycle and hand-off with no transport.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import time
from pathlib import Path
from typing import Any

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import drivers_canopen, drivers_dynamixel, drivers_ur
from drivers.base import Command, CommandKind, ControlConfig
from drivers.lifecycle import ManagedDriver
from drivers.sim.driver import SimDriver
from stubs.plant.base import KinematicPlant


def _plant_baseline(cycles: int = 3000) -> dict[str, Any]:
    async def run() -> list[int]:
        plant = KinematicPlant()
        driver = ManagedDriver(SimDriver(plant))
        await driver.configure(ControlConfig(6, 2_000_000, (-6.28,) * 6, (6.28,) * 6,
                                             (3.14,) * 6))
        await driver.activate()
        samples = []
        for _ in range(cycles):
            began = time.perf_counter_ns()
            q = (await driver.read()).q
            await driver.write(Command(kind=CommandKind.POSITION, q=q))
            samples.append(time.perf_counter_ns() - began)
        await driver.aclose()
        return sorted(samples)

    ordered = asyncio.run(run())
    return {"p50_us": ordered[len(ordered) // 2] / 1e3,
            "p99_us": ordered[int(0.99 * len(ordered))] / 1e3}


def _row(name: str, p50: float | None, p99: float | None, rate: Any) -> str:
    cell = lambda v: f"{v:>9.0f}" if v is not None else f"{'-':>9}"  # noqa: E731
    return f"{name:<26}{cell(p50)}{cell(p99)}{rate!s:>12}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    seconds = parser.parse_args().seconds
    baseline = _plant_baseline()
    ur = drivers_ur.measure(seconds)
    dxl = drivers_dynamixel.measure(seconds)
    can = drivers_canopen.measure(seconds)
    print(f"{'driver (write + read)':<26}{'p50 us':>9}{'p99 us':>9}{'max rate':>12}")
    print(_row("sim plant (baseline)", baseline["p50_us"], baseline["p99_us"], "-"))
    best = ur["rates"].get(ur["highest_sustainable_hz"] or 500, {})
    print(_row("ur_rtde", best.get("p50_us"), best.get("p99_us"),
               f"{ur['highest_sustainable_hz'] or 'none'} Hz"))
    latency = dxl["cycle_latency"]
    print(_row("dynamixel", latency["p50_us"], latency["p99_us"],
               f"{dxl['highest_sustainable_hz'] or 'none'} Hz"))
    for transport in ("virtual", "udp_multicast"):
        figures = can[transport]
        rate = figures["sustainable_hz"] or 100
        row = figures["rates"].get(rate, {})
        print(_row(f"canopen402 ({transport})", row.get("p50_us"), row.get("p99_us"),
                   f"{figures['sustainable_hz'] or 'none'} Hz"))
    print("ratios are against the plant baseline measured in this run:")
    for name, p50 in (("dynamixel", latency["p50_us"]), ("ur_rtde", best.get("p50_us"))):
        if p50:
            print(f"  {name}: {p50 / baseline['p50_us']:.0f}x the baseline p50")


if __name__ == "__main__":
    main()
