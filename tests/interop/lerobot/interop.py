"""``make interop``: the simulated cell with its cameras, driven by LeRobot's own PolicyServer
(0.4.4, serving a randomly initialised ACT saved locally) through the LeRobot sidecar.

Builds the LeRobot venv (``requirements.lock``: torch from ``LEROBOT_WHEELS``, /opt/wheels by
default, and about 60 pinned packages) and the sidecar's, saves the ACT under
``build/lerobot-act`` once, starts the server (``lerobot_side.py serve``, port 8080, 30 fps, one
torch thread) and the sidecar (``sidecars/lerobot/example.toml``, port 8766), then runs
``warden run manifests/sim-lerobot.toml`` and prints what happened: the run's summary (cycles,
chunks admitted and refused with their reasons) and the sidecar's inference times. A random ACT
proposes joint targets that have nothing to do with the cell: expect warden to refuse them and
the arm to stay where the classical owners put it, and no verified cycle (warden exits 1).
Exit status: 0 when LeRobot's chunks reached warden's core through the sidecar and every reply
was read (whatever the core decided), 1 otherwise.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import socket
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from tools.venvs import ROOT, locked_venv, sidecar_python

HERE = Path(__file__).parent
POLICY = ROOT / "build" / "lerobot-act"
LEROBOT_PORT = 8080
SIDECAR_CONFIG = ROOT / "sidecars" / "lerobot" / "example.toml"
MANIFEST = ROOT / "manifests" / "sim-lerobot.toml"
SERVER_ENV = {"OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1", "PYTHONPATH": str(HERE)}


def lerobot_python() -> Path:
    wheels = os.environ.get("LEROBOT_WHEELS", "/opt/wheels")
    return locked_venv("lerobot", HERE / "requirements.lock",
                       pip_options=("--find-links", wheels))


@contextlib.contextmanager
def child(command: list[str], log: Path, env: dict[str, str] | None = None,
          stdout: int | None = None) -> Iterator[subprocess.Popen[str]]:
    process = subprocess.Popen(command, cwd=ROOT, stdout=stdout, stderr=log.open("w"),
                               text=True, env={**os.environ, **(env or {})})
    try:
        yield process
    finally:
        process.terminate()
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()


def wait_for_port(port: int, timeout_s: float, log: Path) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.5):
            return
        time.sleep(0.2)
    raise SystemExit(f"the LeRobot server did not listen on {port}:\n{log.read_text()[-2000:]}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=1)
    parser.add_argument("--out", type=Path, default=ROOT / "build" / "interop-lerobot")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    python = lerobot_python()
    sidecar = sidecar_python()
    print(f"venvs ready in {time.monotonic() - started:.0f} s: {python}, {sidecar}")
    if not (POLICY / "model.safetensors").exists():
        subprocess.run([str(python), str(HERE / "lerobot_side.py"), "make-policy", str(POLICY)],
                       cwd=ROOT, env={**os.environ, **SERVER_ENV}, check=True)
    server_log, sidecar_log = args.out / "lerobot-server.log", args.out / "sidecar.log"
    with child([str(python), str(HERE / "lerobot_side.py"), "serve", "--host=127.0.0.1",
                f"--port={LEROBOT_PORT}", "--fps=30"], server_log, SERVER_ENV):
        wait_for_port(LEROBOT_PORT, 90.0, server_log)
        with child([str(sidecar), "-m", "sidecars.lerobot", str(SIDECAR_CONFIG)], sidecar_log,
                   stdout=subprocess.PIPE) as side:
            assert side.stdout is not None
            print(f"sidecar: {side.stdout.readline().strip()}")
            summary = args.out / "summary.json"
            run = subprocess.run(
                [str(ROOT / ".venv" / "bin" / "warden"), "run", str(MANIFEST), "--cycles",
                 str(args.cycles), "--json", str(summary), "--journal-dir",
                 str(args.out / "runs"), "--log-format", "json"],
                cwd=ROOT, stdout=(args.out / "warden.log").open("w"),
                stderr=subprocess.STDOUT, timeout=600, check=False)
    return report(run.returncode, summary, sidecar_log)


def report(code: int, summary: Path, sidecar_log: Path) -> int:
    print(f"warden run exited {code}")
    chunks = 0
    if summary.exists():
        data = json.loads(summary.read_text())
        shown = ("cycles", "decisions", "refusals_by_phase_and_reason",
                 "inference_round_trip_ms", "link")
        print(json.dumps({key: data[key] for key in shown if key in data}, indent=1))
        print(f"fallback transitions: {len(data.get('fallback_transitions', []))}")
        chunks = data.get("link", {}).get("chunks_in", 0)
    text = sidecar_log.read_text()
    times = [float(m) for m in re.findall(r"actions in ([0-9.]+) ms", text)]
    if times:
        print(f"sidecar: {len(times)} chunks from LeRobot, its round trip p50 "
              f"{statistics.median(times):.0f} ms, max {max(times):.0f} ms")
    refused = text.count("reply refused")
    print(f"sidecar: {refused} replies refused; logs in {sidecar_log.parent}")
    return 0 if chunks > 0 and refused == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
