"""The control loop's rate in every fallback state, per driver, against its clean RUNNING rate.

    python bench/fallback_rate.py [--window 3] [--root DIR ...] [MANIFEST ...]

Each manifest (default: the simulated cell and the three emulated driver cells) runs on the
wall clock in its own process, once per ``--root`` (a warden checkout: give this one and a
base checkout to compare them on the same machine in the same run). A tick hook drives the
run through the states one after another, ``--window`` seconds each, with the events the
operator socket and the device would feed the core:

- RUNNING: the clean run, the level the others are held to;
- SAFE_HOLD: ``takeover`` then ``release`` (an operator hold), then ``accept-recovery``;
- E_STOP: ``stop`` (the operator's e-stop; the driver stays up and is commanded STOP every
  tick), an ``accept-recovery`` refused in E_STOP half-way, then ``reset`` and
  ``accept-recovery``;
- CONTROLLER_STOP: the device refused a write (the ``controller`` event the loop feeds on a
  refused command): STOP every tick with the driver still up.

Ticks are counted only while the driver is up: a driver that faulted (an emulator starved on a
loaded machine) is no longer called, and the states after it would measure nothing; the
driver's faults are printed under each run.

Printed per driver and state: ticks, deadline misses (a tick later than half a period, or a
period skipped, as ``warden run`` counts them) as a share of the periods (ticks plus misses:
a skipped period is a miss without a tick), p99 lateness,
and the longest gap between two ticks (a gap past the unit's ``WatchdogSec`` would have had
systemd kill the process). Figures are printed, never asserted: the machine is shared.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path
from typing import Any

import msgspec

if __package__ in (None, ""):  # run as a script: this directory's operator.py would stand in
    _HERE = Path(__file__).resolve().parent  # for the standard library's ``operator``
    sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ("sim-ur5e.toml", "sim-ur5e-rtde.toml", "sim-dynamixel.toml", "sim-canopen.toml")
STATES = ("RUNNING", "SAFE_HOLD", "E_STOP", "CONTROLLER_STOP")


class Walk:
    """The tick hook: one window per state, each entered by the events that reach it live.

    Counts are kept per window, for ticks whose fallback mode is the window's state."""

    def __init__(self, window_s: float, events: Any) -> None:
        self.window_ns = round(window_s * 1e9)
        self.ev = events
        self.started: int | None = None
        self.last_wake: int | None = None
        self.misses_seen = 0
        self.stats: dict[str, dict[str, Any]] = {
            s: {"ticks": 0, "misses": 0, "lateness_us": [], "max_gap_ms": 0.0} for s in STATES}
        self.done: set[str] = set()

    def __call__(self, context: Any) -> bool:
        now = time.monotonic_ns()
        gap = 0 if self.last_wake is None else now - self.last_wake
        self.last_wake = now
        if self.started is None:
            self.started = now + self.window_ns // 3  # start-up settles first
        misses = context.misses - self.misses_seen
        self.misses_seen = context.misses
        if now < self.started:
            return False
        index, into = divmod(now - self.started, self.window_ns)
        if index >= len(STATES):
            return True
        state = STATES[index]
        self._steer(context, state, into)
        mode = str(context.cell.core.status().mode)
        # A faulted driver is no longer called (the stop path is not exercised): not counted.
        up = str(context.cell.driver.state) == "ACTIVE"
        if mode == state and state in self.done and up:
            stats = self.stats[state]
            stats["ticks"] += 1
            stats["misses"] += misses
            stats["lateness_us"].append(context.lateness_ns[-1] / 1000.0)
            stats["max_gap_ms"] = max(stats["max_gap_ms"], gap / 1e6)
        return False

    def _steer(self, context: Any, state: str, into: int) -> None:
        gateway = context.cell.gateway
        ev = self.ev
        t = gateway.now_ns()
        mode = str(context.cell.core.status().mode)

        def operator(action: Any) -> None:
            gateway.feed(ev.OperatorEvent(t=t, action=action))

        if state not in self.done:
            self.done.add(state)
            if state == "SAFE_HOLD":
                operator(ev.OperatorAction.TAKEOVER)
                operator(ev.OperatorAction.RELEASE)
            elif state == "E_STOP":
                operator(ev.OperatorAction.ESTOP)
            elif state == "CONTROLLER_STOP":
                gateway.feed(ev.ControllerEvent(t=t, status=ev.ControllerStatus.REJECT,
                                                reason=ev.ReasonCode.CONTROLLER_REJECT))
            return
        if state == "E_STOP" and into > self.window_ns // 2 and not getattr(self, "_tried", 0):
            self._tried = 1
            operator(ev.OperatorAction.ACCEPT_RECOVERY)  # refused in E_STOP, as on the cell
        if into > self.window_ns - 300_000_000 and mode not in ("RUNNING", "DEGRADED"):
            # the last 300 ms of a window: back toward RUNNING for the next state
            if mode == "E_STOP":
                operator(ev.OperatorAction.RESET)
            elif mode == "CONTROLLER_STOP":
                gateway.feed(ev.ControllerEvent(t=t, status=ev.ControllerStatus.OK))
                operator(ev.OperatorAction.ACCEPT_RECOVERY)
            else:
                operator(ev.OperatorAction.ACCEPT_RECOVERY)


def inner(manifest_name: str, window_s: float) -> None:
    """One cell, in this process (the checkout on sys.path is the one measured)."""
    from assurance.reasons import ReasonCode
    from kernel.cli_run import run_wall
    from kernel.core import events
    from kernel.manifest import load_manifest

    loaded = load_manifest(Path("manifests") / manifest_name)
    cell = msgspec.structs.replace(loaded.cell, cycles=1000, simulated_operator=False,
                               cycle_timeout_s=600.0)
    walk = Walk(window_s, types.SimpleNamespace(**vars(events), ReasonCode=ReasonCode))
    with tempfile.TemporaryDirectory() as journals:
        # Its own operator socket: a warden elsewhere on the machine may serve the default one.
        operator = msgspec.structs.replace(loaded.operator, socket=f"{journals}/operator.sock")
        summary = run_wall(dataclasses.replace(loaded, cell=cell, operator=operator),
                           Path(journals), walk)
    result = {}
    for state, stats in walk.stats.items():
        lateness = sorted(stats.pop("lateness_us"))
        stats["p99_us"] = lateness[int(0.99 * (len(lateness) - 1))] if lateness else None
        result[state] = stats
    print(json.dumps({"states": result, "faults": summary["driver"]["faults"],
                      "module": events.__file__}))


def run_inner(root: Path, manifest: str, window_s: float) -> dict[str, Any]:
    command = [sys.executable, str(Path(__file__).resolve()), "--inner", manifest,
               "--window", str(window_s)]
    env = {**os.environ, "PYTHONPATH": str(root)}
    done = subprocess.run(command, cwd=root, env=env, capture_output=True, text=True,
                          timeout=300, check=False)
    last = done.stdout.strip().splitlines()[-1:] or [""]
    if not last[0].startswith("{"):
        raise RuntimeError(f"{manifest} at {root}: no result (exit {done.returncode}):\n"
                           f"{done.stderr[-3000:]}")
    result: dict[str, Any] = json.loads(last[0])
    if not result["module"].startswith(str(root)):
        raise RuntimeError(f"{manifest}: measured {result['module']}, not the checkout {root}")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("manifests", nargs="*", default=list(DEFAULT))
    parser.add_argument("--window", type=float, default=3.0, help="seconds in each state")
    parser.add_argument("--root", type=Path, action="append",
                        help="a warden checkout to run (repeatable; default: this one)")
    parser.add_argument("--inner", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.inner:
        sys.path.insert(0, os.getcwd())
        inner(args.manifests[0], args.window)
        return
    roots = [r.resolve() for r in (args.root or [ROOT])]
    load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    print(f"fallback states at {args.window:g} s each, {os.cpu_count()} CPUs, load {load}")
    print(f"{'manifest':<20} {'root':<22} {'state':<16} {'ticks':>6} {'miss %':>7} "
          f"{'p99 us':>7} {'max gap ms':>10}")
    for manifest in args.manifests:
        for root in roots:
            try:
                result = run_inner(root, manifest, args.window)
            except (RuntimeError, subprocess.TimeoutExpired) as error:  # the next cell still runs
                reason = str(error).strip().splitlines()[-1][-120:]
                print(f"{manifest:<20} {str(root)[-22:]:<22} not measured: {reason}")
                continue
            for state, s in result["states"].items():
                ticks = s["ticks"]
                periods = ticks + s["misses"]  # a skipped period is a miss without a tick
                rate = 100.0 * s["misses"] / periods if ticks else float("nan")
                p99 = s["p99_us"] if s["p99_us"] is not None else float("nan")
                print(f"{manifest:<20} {str(root)[-22:]:<22} {state:<16} {ticks:>6} "
                      f"{rate:>6.2f}% {p99:>7.0f} {s['max_gap_ms']:>10.1f}")
            print(f"{'':<20} {'':<22} driver faults: {result['faults']}")


if __name__ == "__main__":
    main()
