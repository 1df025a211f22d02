"""How soon the core learns that the policy server is gone, in the simulated cell on the wall clock.

Each run is the simulated cell (``manifests/sim-ur5e.toml``, one cycle) live: the 500 Hz loop,
the MuJoCo plant and the reference policy server as a child process on loopback. Once the
cycle reaches ``--phase`` (PRE_CONTACT: the policy drives; CONTACT: the contact owner
descends), the bench stops the server with SIGSTOP (hung: its sockets stay open, nothing
answers) or SIGKILL (dead: the kernel closes its sockets) and reads from the decision log when
the core entered DEGRADED with LINK_LOST. Printed per run: the detection time, and the bound
the docs state (``policy.heartbeat_timeout_ms + policy.heartbeat_interval_ms``, measured from
the server's last frame, so the time from the signal is at most that). Figures are printed,
never asserted.

    .venv/bin/python bench/link_loss.py [--runs 3] [--phase PRE_CONTACT|CONTACT]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import statistics
import sys
import tempfile
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make the repository importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from kernel.app.live import run_live
from kernel.app.session import RunContext
from kernel.manifest import load_manifest
from kernel.shell.loop import run
from skills.phases import TaskPhase

ROOT = Path(__file__).resolve().parents[1]
SIGNALS = {"hung": signal.SIGSTOP, "killed": signal.SIGKILL}


def _policy_server_pid() -> int:
    """The reference server this process launched (``python -m stubs.policy_server``), from
    /proc."""
    me = str(os.getpid())
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        parent = stat.rsplit(")", 1)[1].split()[1]
        if parent == me and b"stubs.policy_server" in cmdline:
            return int(entry.name)
    raise RuntimeError("no policy server child found")


class _LoseServer:
    """The run's tick hook: signals the server once the phase is reached; keeps the instant."""

    def __init__(self, phase: TaskPhase, signum: int) -> None:
        self.phase, self.signum = phase, signum
        self.sent_ms: float | None = None
        self.pid: int | None = None

    def __call__(self, context: RunContext) -> bool:
        if self.sent_ms is None and context.cell.core.status().phase is self.phase:
            self.pid = _policy_server_pid()
            os.kill(self.pid, self.signum)
            self.sent_ms = context.cell.gateway.now_ns() * 1e-6
        return False


def one_run(phase: TaskPhase, signum: int) -> float | None:
    manifest = load_manifest(ROOT / "manifests" / "sim-ur5e.toml")
    hook = _LoseServer(phase, signum)
    with tempfile.TemporaryDirectory() as journals:
        try:
            summary = run(run_live(manifest, Path(journals), hook=hook))
        finally:
            if hook.pid is not None and signum == signal.SIGSTOP:
                with contextlib.suppress(ProcessLookupError):  # a restart replaced it
                    os.kill(hook.pid, signal.SIGKILL)
    if hook.sent_ms is None:
        return None
    lost = [t for t in summary["fallback_transitions"]
            if t["t"] >= hook.sent_ms and t["trigger"] == "LINK_LOST"]
    return lost[0]["t"] - hook.sent_ms if lost else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--phase", choices=("PRE_CONTACT", "CONTACT"), default="PRE_CONTACT")
    args = parser.parse_args(argv)
    policy = load_manifest(ROOT / "manifests" / "sim-ur5e.toml").policy
    bound = policy.heartbeat_timeout_ms + policy.heartbeat_interval_ms
    print(f"link loss in {args.phase}, simulated cell; bound {bound:g} ms from the last frame "
          f"(heartbeat timeout {policy.heartbeat_timeout_ms:g} + interval "
          f"{policy.heartbeat_interval_ms:g})")
    for name, signum in SIGNALS.items():
        times = [one_run(TaskPhase(args.phase), signum) for _ in range(args.runs)]
        seen = [t for t in times if t is not None]
        shown = ", ".join("-" if t is None else f"{t:.0f}" for t in times)
        middle = f"median {statistics.median(seen):.0f} ms" if seen else "no detection"
        print(f"  {name:7s} signal → DEGRADED (LINK_LOST): {shown} ms; {middle}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
