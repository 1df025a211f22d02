"""Takeover latency at the operator socket of a running simulated cell.

A real ``warden run`` of ``manifests/sim-ur5e.toml`` (the MuJoCo cell on the wall clock, 2 ms
control period, its simulated operator off, an operator socket in a temporary directory) is
commanded from this process through the same client ``warden operator`` uses
(``kernel.cli_operator.send``): ``--takeovers`` times ``takeover`` (HUMAN_RECOVERY), then
``release`` (SAFE_HOLD) and ``accept-recovery`` (back to RUNNING), each takeover at a random
instant (a pause of 100 to 300 ms before it, fixed seed) so that it lands anywhere in a period.

Printed, p50 / p95 / max:
- takeover latency: command received by the server → the first control tick owned by the
  human has run, the ``latency_ms`` the takeover answer carries (and ``warden operator
  takeover`` prints);
- the client's round trip for that takeover (connect, send, the server waits for that tick,
  answer received);
- the round trip of ``status`` (a query: no tick to wait for), for comparison.
The round trips are the socket's, in a process that has already imported the client: a
``warden operator`` command line also pays its interpreter's start-up, seconds on a loaded
machine. Figures are printed, never asserted: the machine is shared.

    .venv/bin/python bench/operator.py [--takeovers 100] [--seed 1]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # run as a script: make the repository importable, and not
    # this directory (this file would stand in for the standard library's ``operator``)
    _HERE = Path(__file__).resolve().parent
    sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
    sys.path.insert(0, str(_HERE.parent))

from kernel.cli_operator import send

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = ROOT / "manifests" / "sim-ur5e.toml"
START_TIMEOUT_S = 60.0


def _manifest(directory: Path, socket: Path) -> Path:
    """The simulated cell, many cycles (the bench ends the run), no simulated operator."""
    text = MANIFEST.read_text()
    old = "cycles = 3"
    if text.count(old) != 1:
        raise SystemExit(f"{MANIFEST}: expected one {old!r}")
    text = text.replace(old, "cycles = 1000\nsimulated_operator = false")
    path = directory / "cell.toml"
    path.write_text(text + f'\n[operator]\nsocket = "{socket}"\n')
    return path


def _start(directory: Path, socket: Path) -> subprocess.Popen[bytes]:
    warden = subprocess.Popen(
        [sys.executable, "-m", "kernel.cli", "run", str(_manifest(directory, socket)),
         "--journal-dir", str(directory / "runs"), "--log-format", "json"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=(directory / "warden.log").open("wb"))
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        if warden.poll() is not None:
            log = (directory / "warden.log").read_text()[-2000:]
            raise SystemExit(f"warden exited {warden.returncode}:\n{log}")
        try:
            if send(str(socket), "status", 2.0).get("mode") == "RUNNING":
                return warden
        except (OSError, ValueError):
            pass
        time.sleep(0.05)
    warden.kill()
    raise SystemExit("warden's operator socket never answered")


def _timed(socket: Path, command: str) -> tuple[dict[str, Any], float]:
    """The answer, and the client's round trip in ms."""
    started = time.perf_counter_ns()
    answer = send(str(socket), command, 5.0)
    return answer, (time.perf_counter_ns() - started) / 1e6


def _back_to_running(socket: Path) -> None:
    """release, then accept-recovery until RUNNING (a recovery without a valid session goes
    to DEGRADED first; the cell's link then handshakes again by itself)."""
    send(str(socket), "release", 5.0)
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        mode = send(str(socket), "status", 2.0).get("mode")
        if mode == "RUNNING":
            return
        if mode in ("SAFE_HOLD", "HUMAN_RECOVERY", "REPLAN_OR_RETREAT", "CONTACT_FALLBACK"):
            send(str(socket), "accept-recovery", 5.0)
        time.sleep(0.05)
    raise SystemExit(f"the cell did not return to RUNNING: {send(str(socket), 'status', 2.0)}")


def measure(takeovers: int, seed: int) -> dict[str, Any]:
    rng = random.Random(seed)
    latency: list[float] = []
    takeover_rtt: list[float] = []
    status_rtt: list[float] = []
    phases: dict[str, int] = {}
    missed = 0
    with tempfile.TemporaryDirectory(prefix="warden-operator-bench-") as tmp:
        directory = Path(tmp)
        socket = directory / "operator.sock"
        warden = _start(directory, socket)
        try:
            for _ in range(takeovers):
                time.sleep(rng.uniform(0.1, 0.3))
                before, rtt = _timed(socket, "status")
                status_rtt.append(rtt)
                answer, rtt = _timed(socket, "takeover")
                if not answer.get("took_over"):
                    missed += 1
                    print(f"  takeover not confirmed: {json.dumps(answer)[:300]}", file=sys.stderr)
                else:
                    latency.append(float(answer["latency_ms"]))
                    takeover_rtt.append(rtt)
                    phases[before["phase"]] = phases.get(before["phase"], 0) + 1
                _back_to_running(socket)
        finally:
            if warden.poll() is None:
                warden.send_signal(signal.SIGTERM)
                try:
                    warden.wait(timeout=60)
                except subprocess.TimeoutExpired:
                    warden.kill()
                    warden.wait()
    return {"latency": latency, "takeover_rtt": takeover_rtt, "status_rtt": status_rtt,
            "phases": phases, "missed": missed}


def _quantiles(values: list[float]) -> str:
    if not values:
        return "no samples"
    ordered = sorted(values)
    p95 = ordered[min(len(ordered) - 1, round(0.95 * (len(ordered) - 1)))]
    return (f"p50 {statistics.median(ordered):6.2f}  p95 {p95:6.2f}  max {ordered[-1]:6.2f} ms"
            f"  (min {ordered[0]:.2f}, n={len(ordered)})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--takeovers", type=int, default=100, help="takeover/release rounds")
    parser.add_argument("--seed", type=int, default=1, help="for the pauses between rounds")
    args = parser.parse_args()
    started = time.monotonic()
    result = measure(args.takeovers, args.seed)
    load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    print(f"operator takeovers of the simulated cell (sim-ur5e, 2 ms control period), "
          f"{os.cpu_count()} CPUs, load average {load}, {time.monotonic() - started:.0f} s")
    print(f"  takeover latency (received -> first human tick) {_quantiles(result['latency'])}")
    print(f"  takeover round trip (client)                    {_quantiles(result['takeover_rtt'])}")
    print(f"  status round trip (client)                      {_quantiles(result['status_rtt'])}")
    phases = ", ".join(f"{phase} {count}" for phase, count in sorted(result["phases"].items()))
    print(f"  taken over in: {phases}; not confirmed within 2 s: {result['missed']}")


if __name__ == "__main__":
    main()
