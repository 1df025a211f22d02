"""CiA 402 driver: control-cycle latency and the highest sustainable rate, six drives.

One control cycle, through ``ManagedDriver``: ``write`` (six RPDOs, then SYNC), wait until every
drive's TPDOs answering that SYNC are in, ``read``. Measured on ``virtual`` (emulator in this
process, sharing its GIL) and on ``udp_multicast`` (emulator in its own process), at 100, 250,
500 and 1000 Hz, on uvloop as the kernel runs. A rate is sustainable when at most 1 % of its
cycles miss (the cycle took longer than its period) and the loop kept at least 95 % of the rate.

    .venv/bin/python bench/drivers_canopen.py [seconds]

Figures are printed, never asserted: they depend on the machine and its load.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # run as a script: make the repository (and its tests) importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
import uvloop

from drivers.base import Command, CommandKind, DriverError
from drivers.canopen402 import CiA402Settings
from drivers.canopen402.driver import CiA402Driver
from drivers.lifecycle import ManagedDriver
from stubs.cia402_drive import DriveEmulator
from stubs.cia402_drive.launch import unique_udp_bus
from stubs.process import EmulatorProcess
from tests.drivers import cia402_testbed as arm

RATES_HZ = (100, 250, 500, 1000)
MAX_MISS_FRACTION = 0.01
MIN_RATE_FRACTION = 0.95
ANSWER_WAIT_S = 0.1
AMPLITUDE_RAD = 0.05
"""A slow sine on every joint: real motion, well inside the drives' following-error window."""


def measure(seconds: float = 5.0) -> dict[str, Any]:
    """Per transport: per-rate latency figures, and the highest sustainable rate.

    ``seconds`` is the measuring time per transport, shared among the rates.
    """
    per_rate_s = max(1.0, seconds / len(RATES_HZ))
    results = {}
    for transport in ("virtual", "udp_multicast"):
        with asyncio.Runner(loop_factory=uvloop.new_event_loop) as runner:
            results[transport] = runner.run(_measure_transport(transport, per_rate_s))
    return results


async def _measure_transport(transport: str, per_rate_s: float) -> dict[str, Any]:
    rates: dict[int, dict[str, Any]] = {}
    with _emulated_arm(transport) as settings:
        for rate in RATES_HZ:
            rates[rate] = await _measure_rate(settings, rate, per_rate_s)
    sustainable = [r for r, f in rates.items() if f["miss_fraction"] <= MAX_MISS_FRACTION
                   and f["achieved_hz"] >= MIN_RATE_FRACTION * r]
    return {"rates": rates, "sustainable_hz": max(sustainable, default=0)}


@contextlib.contextmanager
def _emulated_arm(transport: str) -> Iterator[CiA402Settings]:
    if transport == "virtual":
        channel = arm.unique_virtual_channel()
        with DriveEmulator(arm.emulator_config("virtual", channel)):
            yield arm.driver_settings("virtual", channel)
        return
    group, port = unique_udp_bus()
    with EmulatorProcess("stubs.cia402_drive", *arm.emulator_args(group, port)):
        yield arm.driver_settings("udp_multicast", group, udp_port=port)


async def _measure_rate(settings: CiA402Settings, rate_hz: int,
                        seconds: float) -> dict[str, Any]:
    period_s = 1.0 / rate_hz
    driver = ManagedDriver(CiA402Driver(settings))
    try:
        await driver.configure(arm.control(period_ns=round(period_s * 1e9)))
        await driver.activate()
        return await _run_loop(driver, period_s, seconds)
    except DriverError as error:  # a rate the setup cannot keep up with is a result too
        return {**_figures([], 0, 0, 1.0), "miss_fraction": 1.0, "error": str(error)}
    finally:
        await driver.aclose()


async def _run_loop(driver: ManagedDriver, period_s: float, seconds: float) -> dict[str, Any]:
    cycle = driver.driver.cycle if isinstance(driver.driver, CiA402Driver) else None
    home = np.array((await driver.read()).q)
    loop = asyncio.get_running_loop()
    latencies: list[int] = []
    misses = cycles = 0
    started = due = loop.time()
    while loop.time() - started < seconds:
        phase = 2 * math.pi * 0.5 * (loop.time() - started)
        target = tuple((home + AMPLITUDE_RAD * math.sin(phase)).tolist())
        t0 = time.perf_counter_ns()
        await driver.write(Command(kind=CommandKind.POSITION, q=target))
        # One cycle in flight: wait for its answer even when late, so that a rate the setup
        # cannot keep shows as misses and a lower achieved rate, not as an ever-growing queue.
        answered = cycle is not None and await cycle.wait_completed(cycle.cycle, ANSWER_WAIT_S)
        await driver.read()
        cycles += 1
        latency = time.perf_counter_ns() - t0
        latencies.append(latency)
        misses += int(not answered or latency > period_s * 1e9)
        due += period_s
        delay = due - loop.time()
        if delay > 0:
            await asyncio.sleep(delay)
        elif delay < -period_s:
            due = loop.time()  # fell behind (a stall): do not catch up in a burst
    elapsed = loop.time() - started
    return _figures(latencies, cycles, misses, elapsed)


def _figures(latencies: list[int], cycles: int, misses: int, elapsed: float) -> dict[str, Any]:
    ordered = np.sort(np.array(latencies or [0])) / 1000.0
    return {
        "p50_us": float(np.percentile(ordered, 50)),
        "p99_us": float(np.percentile(ordered, 99)),
        "max_us": float(ordered[-1]),
        "cycles": float(cycles),
        "achieved_hz": cycles / elapsed,
        "miss_fraction": misses / max(cycles, 1),
    }


def _print(results: dict[str, Any]) -> None:
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print("CiA 402, 6 drives, write (RPDOs + SYNC) -> all TPDOs -> read, via ManagedDriver")
    print(f"host load average (1, 5, 15 min): {load} on {os.cpu_count()} cores")
    print(f"{'transport':<14}{'rate':>6}{'p50 us':>10}{'p99 us':>10}{'max us':>10}"
          f"{'achieved':>10}{'missed':>9}")
    for transport, result in results.items():
        for rate, f in result["rates"].items():
            missed = 100 * f["miss_fraction"]
            print(f"{transport:<14}{rate:>6}{f['p50_us']:>10.0f}{f['p99_us']:>10.0f}"
                  f"{f['max_us']:>10.0f}{f['achieved_hz']:>9.0f}/s{missed:>8.1f}%"
                  + (f"  ({f['error']})" if "error" in f else ""))
        print(f"{transport:<14}highest sustainable rate: {result['sustainable_hz']} Hz "
              f"(<= {100 * MAX_MISS_FRACTION:.0f}% missed, >= {100 * MIN_RATE_FRACTION:.0f}% of "
              "the rate)")


if __name__ == "__main__":
    _print(measure(float(sys.argv[1]) if len(sys.argv) > 1 else 5.0))
