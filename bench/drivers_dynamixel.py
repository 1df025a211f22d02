"""Benchmark: one control cycle (sync write of 6 goals + fast sync read of 6 states) through
ManagedDriver, real dynamixel_sdk, against the bus emulator on a pty. Figures are printed, never
asserted: ``python bench/drivers_dynamixel.py [seconds]``.

Two measurements:
- cycle latency: back-to-back cycles, the time from ``write`` to the end of ``read``;
- control rate: cycles paced at 100/250/500/1000 Hz with absolute deadlines. A rate counts as
  sustainable when the loop achieved at least 98 % of it and fewer than 1 % of cycles were busy
  for longer than one period. Pacing uses ``asyncio.sleep`` (uvloop when installed), whose timer
  has whole-millisecond resolution (bench/loop.py measures it), so at 1 kHz the loop timer
  rather than the bus may be what fails.

The emulator answers in Python on the same two cores, so these numbers bound a real bus from
above only loosely: on hardware the wire time (about 120 us for this exchange at 1 Mbps) and the
adapter's latency timer dominate instead.
"""

from __future__ import annotations

import asyncio
import json
import sys
import time
from typing import Any

from drivers.base import Command, CommandKind, ControlConfig
from drivers.dynamixel.driver import DynamixelDriver
from drivers.dynamixel.settings import DynamixelSettings
from drivers.lifecycle import ManagedDriver
from stubs.dynamixel_bus.launch import WIDE_TIMING, BusEmulator

RATES_HZ = (100, 250, 500, 1000)
SERVOS = 6


def _percentile(values: list[float], p: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(p / 100.0 * len(ordered)))] if ordered else 0.0


async def _cycle(driver: ManagedDriver, hold: Command) -> float:
    """One write + read; returns its duration in microseconds."""
    started = time.perf_counter()
    await driver.write(hold)
    await driver.read()
    return (time.perf_counter() - started) * 1e6


async def _latency(driver: ManagedDriver, hold: Command, seconds: float) -> dict[str, Any]:
    durations: list[float] = []
    until = time.perf_counter() + seconds
    while time.perf_counter() < until:
        durations.append(await _cycle(driver, hold))
    return {"cycles": len(durations), "p50_us": round(_percentile(durations, 50)),
            "p99_us": round(_percentile(durations, 99)), "max_us": round(max(durations))}


async def _paced(driver: ManagedDriver, hold: Command, rate_hz: int, seconds: float) -> dict:
    period = 1.0 / rate_hz
    cycles = max(1, int(seconds * rate_hz))
    busy: list[float] = []
    started = deadline = time.perf_counter()
    for _ in range(cycles):
        busy.append(await _cycle(driver, hold))
        deadline += period
        delay = deadline - time.perf_counter()
        if delay > 0:
            await asyncio.sleep(delay)
        elif -delay > period:
            deadline = time.perf_counter()  # fell a whole period behind: do not burst to catch up
    achieved = cycles / (time.perf_counter() - started)
    overruns = sum(b > period * 1e6 for b in busy) / cycles
    return {"rate_hz": rate_hz, "achieved_hz": round(achieved, 1),
            "overrun_fraction": round(overruns, 4), "busy_p99_us": round(_percentile(busy, 99)),
            "sustainable": achieved >= 0.98 * rate_hz and overruns < 0.01}


async def _measure_on(port: str, seconds: float) -> dict[str, Any]:
    control = ControlConfig(dof=SERVOS, period_ns=2_000_000, q_lower=(-3.0,) * SERVOS,
                            q_upper=(3.0,) * SERVOS, v_max=(3.0,) * SERVOS)
    driver = ManagedDriver(DynamixelDriver(DynamixelSettings(port=port, **WIDE_TIMING)))
    await driver.configure(control)
    try:
        await driver.activate()
        hold = Command(kind=CommandKind.POSITION, q=(await driver.read()).q)
        latency = await _latency(driver, hold, seconds / 2)
        rates = [await _paced(driver, hold, rate, seconds / 2 / len(RATES_HZ))
                 for rate in RATES_HZ]
        bus = driver.driver.bus if isinstance(driver.driver, DynamixelDriver) else None
        fast = bool(bus and bus.uses_fast_sync_read)
        retries = bus.counters.retries if bus else 0
    finally:
        await driver.aclose()
    sustainable = [r["rate_hz"] for r in rates if r["sustainable"]]
    return {"servos": SERVOS, "fast_sync_read": fast, "cycle_latency": latency, "rates": rates,
            "highest_sustainable_hz": max(sustainable, default=0), "retries": retries}


def _run(coroutine: Any) -> Any:
    try:
        import uvloop  # the kernel's loop; falls back to asyncio's own if missing
    except ImportError:
        return asyncio.run(coroutine)
    return uvloop.run(coroutine)


def measure(seconds: float = 5.0) -> dict[str, Any]:
    """Start an emulator, run both measurements for ``seconds`` in total, stop the emulator."""
    with BusEmulator("--ids", ",".join(str(i) for i in range(1, SERVOS + 1))) as bus:
        return dict(_run(_measure_on(bus.port, seconds)))


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 5.0
    result = measure(seconds)
    latency = result["cycle_latency"]
    print(f"dynamixel: {result['servos']} servos, fast sync read: {result['fast_sync_read']}")
    print(f"  sync write + read cycle: p50 {latency['p50_us']} us, p99 {latency['p99_us']} us "
          f"({latency['cycles']} cycles)")
    for rate in result["rates"]:
        verdict = "ok" if rate["sustainable"] else "NOT sustainable"
        print(f"  {rate['rate_hz']:>5} Hz: achieved {rate['achieved_hz']} Hz, busy p99 "
              f"{rate['busy_p99_us']} us, overruns {rate['overrun_fraction']:.2%}: {verdict}")
    print(f"  highest sustainable rate: {result['highest_sustainable_hz']} Hz")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
