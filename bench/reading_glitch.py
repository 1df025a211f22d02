"""How far the true arm moves during a 200 ms reading glitch, on this checkout and another.

    python bench/reading_glitch.py [--root DIR] [--base DIR] [--runs N] [MANIFEST ...]

``sim-ur5e.toml`` runs in lockstep (virtual clock, in-process plant, the glitch 100 samples
of 2 ms): its figure does not depend on the machine's load. The vendor cells run on the wall
clock through their emulators.

Each manifest's cell runs through its vendor driver and emulator (``run_live`` with a tick
hook, in a process of its own whose ``PYTHONPATH`` is the checkout measured). Once the policy
streams pre-contact chunks, the emulator reports joint 0 0.5 rad off for 200 ms (the plant
does not move by it: ``reading_glitch`` on its control port); from then on the hook samples
the plant's true joints every tick until the glitch is over and the arm is back in the task's
hands (or 0.6 s after the glitch). Printed per checkout and cell: the largest true motion of
any joint from where it was at the onset, the joint, and the fallback transitions the glitch
caused; and the largest distance of a true joint from the last command before the onset (the
test's measure, tests/cell/test_reading_glitch.py). The hook (tests/cell/glitches.py) is
loaded from this checkout by path, so ``--base`` may be an older revision; it needs the
emulators' ``reading_glitch`` (copy this checkout's ``stubs/`` over it: stubs/ changed only by
adding it). Prints figures, asserts nothing.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import msgspec

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ("sim-ur5e.toml", "sim-ur5e-rtde.toml", "sim-dynamixel.toml", "sim-canopen.toml")
LOCKSTEP = "sim-ur5e.toml"
"""Runs on a virtual clock (the in-process plant, lockstep): the one figure no machine load
can disturb, the glitch lasting exactly 100 samples of 2 ms."""


async def _lockstep(manifest: Any, journal_dir: Path, hook: Any) -> dict[str, Any]:
    """kernel/app/lockstep.py's run, with the tick hook a live run has."""
    from kernel.app import standins
    from kernel.app.session import bring_up, finish, open_run
    from kernel.shell.timer import VirtualClock
    from kernel.shell.worker import InlineJobs

    clock = VirtualClock()
    context = open_run(manifest, clock, journal_dir, None)
    cell = context.cell
    InlineJobs(cell.gateway)
    link = standins.load(standins.POLICIES, "local")(cell.context, clock)
    period = cell.core.config.control_period_ns
    budget_ns = round(manifest.cell.cycle_timeout_s * 1e9) * manifest.cell.cycles
    try:
        await bring_up(context)
        link.connect()
        cell.controller.start()
        while not cell.controller.finished and cell.gateway.now_ns() < budget_ns:
            link.deliver_due()
            await cell.controller.tick()
            context.recorder.hand_over_if_due()
            if hook(context):
                break
            clock.advance(period)
    finally:
        await cell.driver.aclose()
        cell.world.close()
        context.recorder.close()
    return finish(context, {"clock": "virtual"})


def child(manifest_name: str) -> None:
    """In the measured checkout: one run, one JSON line on stdout."""
    here = Path(__file__).resolve().parent  # run as a script: bench/drivers.py would shadow
    sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != here]
    spec = importlib.util.spec_from_file_location("glitches", ROOT / "tests/cell/glitches.py")
    if spec is None or spec.loader is None:
        raise SystemExit("cannot load tests/cell/glitches.py")
    glitches = importlib.util.module_from_spec(spec)
    sys.modules["glitches"] = glitches  # its dataclasses look their module up by name
    spec.loader.exec_module(glitches)
    import dataclasses

    from kernel.app.live import run_live
    from kernel.manifest import load_manifest
    from kernel.shell.loop import run

    root = Path(os.environ["PYTHONPATH"].split(os.pathsep)[0])
    loaded = load_manifest(root / "manifests" / manifest_name)
    cell = dataclasses.replace(loaded, cell=msgspec.structs.replace(loaded.cell, cycles=1))
    lockstep = manifest_name == LOCKSTEP
    spec = {"samples": 100} if lockstep else {"duration_ms": 200}
    glitch = glitches.Glitch(glitches.PRE_CONTACT, spec, joint=0, offset=0.5,
                             lasts_s=0.2 if lockstep else None)
    campaign = glitches.GlitchCampaign([glitch])
    with tempfile.TemporaryDirectory() as journals:
        if lockstep:
            summary = run(_lockstep(cell, Path(journals), campaign))
        else:
            summary = run(run_live(cell, Path(journals), hook=campaign))
        journal = [json.loads(line) for line in next(Path(journals).glob("*/journal.jsonl"))
                   .open()]
    injected = glitch.injected_ns
    last = None if injected is None else glitches.last_command(
        journal, injected * 1e-6, cell.core.control_period_ns * 1e-9)
    from_command = [] if last is None else [float(x) for x in glitches.motion_from(glitch,
                                                                                    last.q)]
    transitions = [f"{t['from']}->{t['to']} ({t['trigger']}, "
                   f"{t['t'] - injected * 1e-6:+.0f} ms)"
                   for t in summary.get("fallback_transitions", [])
                   if injected is not None and t["t"] * 1e6 >= injected
                   and (glitch.closed_ns is None or t["t"] * 1e6 <= glitch.closed_ns)]
    excursion = [] if glitch.excursion is None else [float(x) for x in glitch.excursion]
    print(json.dumps({"injected": injected is not None, "closed": glitch.closed_ns is not None,
                      "samples": len(glitch.trace),
                      "excursion": excursion, "from_command": from_command,
                      "transitions": transitions}))


def measure(root: Path, manifest_name: str) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as runtime:
        # The run's operator socket in a directory of its own, not a shared /run/warden.
        env = {**os.environ, "PYTHONPATH": str(root), "RUNTIME_DIRECTORY": runtime}
        done = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child",
                               manifest_name], cwd=root, env=env, capture_output=True,
                              text=True, timeout=300, check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if not lines:
        return {"error": f"exit {done.returncode}: {done.stderr.strip()[-300:]}"}
    return json.loads(lines[-1])


def _row(label: str, manifest_name: str, result: dict[str, Any]) -> str:
    if "error" in result:
        return f"{label:<7} {manifest_name:<20} error: {result['error']}"
    if not result["injected"]:
        return f"{label:<7} {manifest_name:<20} the glitch was never injected"
    excursion, commanded = result["excursion"], result["from_command"] or [float("nan")]
    joint = max(range(len(excursion)), key=excursion.__getitem__)
    return (f"{label:<7} {manifest_name:<20} {excursion[joint]:>8.3f} rad (joint {joint}) "
            f"{max(commanded):>8.3f} rad  {result['samples']:>4}  "
            f"{', '.join(result['transitions']) or 'no fallback'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("manifests", nargs="*", default=list(DEFAULT))
    parser.add_argument("--root", type=Path, default=ROOT, help="the checkout (default: this)")
    parser.add_argument("--base", type=Path, default=None, help="another checkout to compare")
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child)
        return
    roots = [("base", args.base)] if args.base else []
    roots.append(("now", args.root))
    print("a 0.5 rad, 200 ms reading glitch of joint 0 in PRE_CONTACT: the largest true joint "
          "motion from the onset, and from the last command before it")
    for manifest_name in args.manifests:
        for _ in range(args.runs):
            for label, root in roots:
                print(_row(label, manifest_name, measure(root, manifest_name)), flush=True)


if __name__ == "__main__":
    main()
