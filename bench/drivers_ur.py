"""Benchmark: the UR RTDE driver's control cycle through ManagedDriver, against the emulator.

    .venv/bin/python bench/drivers_ur.py [--seconds 5]

For each control rate (125, 250, 500, 1000 Hz) a fresh driver streams a slow sine on joint 0
at that rate, each cycle one ``write`` (servoJ) and one ``read``, paced by absolute deadlines.
Reported per rate: write+read latency p50/p99/max (us), overruns (cycles started more than one
period late: a setpoint tick was lost), stale reads (a read whose controller timestamp did not
advance since the previous read: no new RTDE sample had arrived) and the longest gap between
the controller timestamps of consecutive reads. A rate is sustainable when p99 < period and
there are no overruns and no stale reads. The emulator is a Python process on the same
machine, so its jitter is in the figures. Printed, never asserted.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import sys
import time
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # run as a script: make the repository importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.base import Command, CommandKind, ControlConfig, DriverInitError
from drivers.lifecycle import ManagedDriver
from drivers.ur_rtde.driver import URRTDEDriver
from drivers.ur_rtde.settings import URSettings
from stubs.ur_controller.launch import EmulatedController

RATES_HZ = (125, 250, 500, 1000)
SINE_AMPLITUDE_RAD, SINE_HZ = 0.05, 0.5


def measure(seconds: float = 5.0) -> dict[str, Any]:
    """Run every rate for ``seconds / len(RATES_HZ)`` (at least 1 s each); return the figures."""
    with EmulatedController() as emulator:
        return asyncio.run(_measure_all(emulator.host, max(1.0, seconds / len(RATES_HZ))))


async def _measure_all(host: str, seconds_per_rate: float) -> dict[str, Any]:
    rates = {rate: await _measure_rate(host, rate, seconds_per_rate) for rate in RATES_HZ}
    sustainable = [rate for rate, figures in rates.items() if figures["sustainable"]]
    return {"host": host, "seconds_per_rate": seconds_per_rate, "rates": rates,
            "highest_sustainable_hz": max(sustainable, default=None)}


def _control(rate_hz: int) -> ControlConfig:
    return ControlConfig(dof=6, period_ns=round(1e9 / rate_hz), q_lower=(-6.28,) * 6,
                         q_upper=(6.28,) * 6, v_max=(3.14,) * 6)


async def _measure_rate(host: str, rate_hz: int, seconds: float) -> dict[str, Any]:
    driver = ManagedDriver(URRTDEDriver(URSettings(host=host), name="ur-bench"))
    try:
        await driver.configure(_control(rate_hz))
    except DriverInitError as error:
        await driver.aclose()
        return {"sustainable": False, "refused": str(error)}
    try:
        await driver.activate()
        return await _stream(driver, rate_hz, seconds)
    finally:
        await driver.aclose()


async def _stream(driver: ManagedDriver, rate_hz: int, seconds: float) -> dict[str, Any]:
    period = 1.0 / rate_hz
    start_q = (await driver.read()).q
    arm = driver.driver
    if not isinstance(arm, URRTDEDriver):
        raise TypeError("the benchmark drives a URRTDEDriver")
    latencies_ns: list[int] = []
    overruns = stale = 0
    previous_time, longest_gap = arm.controller_time_s or 0.0, 0.0
    started = deadline = time.monotonic()
    for _ in range(int(seconds * rate_hz)):
        offset = SINE_AMPLITUDE_RAD * math.sin(2 * math.pi * SINE_HZ * (deadline - started))
        target = (start_q[0] + offset, *start_q[1:])
        began = time.perf_counter_ns()
        await driver.write(Command(kind=CommandKind.POSITION, q=target))
        await driver.read()
        latencies_ns.append(time.perf_counter_ns() - began)
        controller_time = arm.controller_time_s or 0.0
        stale += controller_time == previous_time
        longest_gap = max(longest_gap, controller_time - previous_time)
        previous_time = controller_time
        deadline += period
        lateness = time.monotonic() - deadline
        if lateness > period:
            overruns += 1
            deadline = time.monotonic()  # resynchronise instead of bursting to catch up
        elif lateness < 0:
            await asyncio.sleep(-lateness)
    figures = _figures(latencies_ns, period, overruns, stale, driver)
    return {**figures, "longest_sample_gap_ms": longest_gap * 1e3}


def _figures(latencies_ns: list[int], period: float, overruns: int, stale: int,
             driver: ManagedDriver) -> dict[str, Any]:
    ordered = sorted(latencies_ns)

    def percentile(p: float) -> float:
        return ordered[min(len(ordered) - 1, int(p / 100 * len(ordered)))] / 1e3

    p99 = percentile(99)
    return {
        "cycles": len(ordered), "p50_us": percentile(50), "p99_us": p99,
        "max_us": ordered[-1] / 1e3, "overruns": overruns, "stale_reads": stale,
        "write_p50_us": driver.stats["write"].percentile(50) / 1e3,
        "read_p50_us": driver.stats["read"].percentile(50) / 1e3,
        "sustainable": p99 < period * 1e6 and overruns == 0 and stale == 0,
        "state": str(driver.state),
    }


def _print(result: dict[str, Any]) -> None:
    print(f"UR RTDE driver via ManagedDriver, emulator at {result['host']}, "
          f"{result['seconds_per_rate']:.2f} s per rate")
    print(f"{'rate':>6} {'cycles':>7} {'p50 us':>8} {'p99 us':>8} {'max us':>8} "
          f"{'write50':>8} {'read50':>7} {'overrun':>7} {'stale':>6} {'gap ms':>7}  sustainable")
    for rate, f in result["rates"].items():
        if "refused" in f:
            print(f"{rate:>4}Hz  refused: {f['refused']}")
            continue
        print(f"{rate:>4}Hz {f['cycles']:>7} {f['p50_us']:>8.0f} {f['p99_us']:>8.0f} "
              f"{f['max_us']:>8.0f} {f['write_p50_us']:>8.0f} {f['read_p50_us']:>7.0f} "
              f"{f['overruns']:>7} {f['stale_reads']:>6} {f['longest_sample_gap_ms']:>7.1f}  "
              f"{'yes' if f['sustainable'] else 'no'}")
    print(f"highest sustainable rate: {result['highest_sustainable_hz'] or 'none'} Hz")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="total streaming time")
    _print(measure(parser.parse_args(argv).seconds))


if __name__ == "__main__":
    main()
