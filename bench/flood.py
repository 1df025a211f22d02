"""What a misbehaving policy server costs the control loop: deadline misses, clean vs floods.

Each case is the simulated cell (``manifests/sim-ur5e.toml``) run live on the wall clock for
``--seconds``: the 500 Hz control loop on a kernel timer, the MuJoCo plant, the job worker, the
recorder writing a journal, and the reference policy server as a process on loopback. The only
difference between the cases is the server, made to misbehave on every connection by its fault
modes (``stubs/policy_server/faults.py``):

- ``clean``: no fault;
- ``chunk flood``: 15 000 extra chunks a second from the handshake on, each the last answer
  again under a new id (before the first answer, one citing an observation never sent);
- ``junk frames``: 1 MB frames that are not envelopes, 10 a second;
- ``big chunks``: every answer 20 000 actions long (a 960 kB chunk).

For each case it prints the ticks, the deadline misses (a tick later than half a period, or a
skipped period) and the miss rate, the p99 and worst lateness, how fast the journal grew, and
what the link did about it (frames and chunks dropped, oversized frames, violations, restarts,
admissions that waited for a later period). Figures are printed, never asserted: the machine is
shared, so compare the cases within one run. The budgets are the manifest's ``[policy]`` keys
(docs/manifest.md).

    .venv/bin/python bench/flood.py [--seconds 15] [--cases clean,chunk_flood,...]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec

if __package__ in (None, ""):  # run as a script: make the repository importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from kernel.app import standins
from kernel.app.context import CellContext
from kernel.app.live import run_live
from kernel.app.session import RunContext
from kernel.manifest import load_manifest
from kernel.shell.loop import run
from stubs.cell.reference import ReferenceServer

MANIFEST = Path(__file__).resolve().parents[1] / "manifests" / "sim-ur5e.toml"
EVERY_CONNECTION = "affect_connections=1000000"
CASES: dict[str, tuple[str, ...]] = {
    "clean": (),
    "chunk_flood": ("flood_chunks_per_s=15000",),
    "junk_frames": ("junk_frame_bytes=1000000", "junk_frames_per_s=10"),
    "big_chunks": ("big_chunk_rows=20000",),
}


class _FaultyServer(ReferenceServer):
    """The reference server of the manifest, with fault modes on every connection."""

    def __init__(self, context: CellContext, faults: tuple[str, ...]) -> None:
        super().__init__(context)
        self.faults = faults

    def _args(self) -> list[str]:
        extra = [f"--fault={fault}" for fault in (*self.faults, EVERY_CONNECTION)]
        return [*super()._args(), *(extra if self.faults else [])]


def _with_server(faults: tuple[str, ...]) -> Callable[[str, str], Any]:
    """The stand-in registry, but the policy it hands out is the faulty reference server."""
    load = standins.load

    def loader(group: str, name: str) -> Any:
        if group == standins.POLICIES and name == "reference":
            return lambda context: _FaultyServer(context, faults)
        return load(group, name)
    return loader


def _stop_after(seconds: float) -> Callable[[RunContext], bool]:
    def hook(context: RunContext) -> bool:
        return context.cell.gateway.now_ns() >= seconds * 1e9
    return hook


def run_case(name: str, seconds: float, workdir: Path) -> dict[str, Any]:
    manifest = load_manifest(MANIFEST)
    cell = msgspec.structs.replace(manifest.cell, cycles=100)
    manifest = dataclasses.replace(manifest, cell=cell)
    original = standins.load
    standins.load = _with_server(CASES[name])  # type: ignore[assignment]
    try:
        summary = run(run_live(manifest, workdir / name, hook=_stop_after(seconds)))
    finally:
        standins.load = original  # type: ignore[assignment]
    journal = sum(p.stat().st_size for p in (workdir / name).rglob("journal.jsonl"))
    return {"summary": summary, "journal_bytes": journal}


def _row(name: str, result: dict[str, Any], seconds: float) -> str:
    loop, link = result["summary"]["loop"], result["summary"]["link"]
    lateness = loop["lateness_us"]
    dropped = f"{link.get('frames_dropped', 0)}/{link.get('chunks_dropped', 0)}"
    return (f"  {name:<12} {loop['ticks']:>6} {loop['misses']:>6} {100 * loop['miss_rate']:>6.2f}%"
            f" {link.get('frames_in', 0) / seconds:>9.0f}"
            f" {lateness.get('p99', 0):>8.0f} {lateness.get('max', 0):>8.0f}"
            f" {result['journal_bytes'] / seconds / 1e3:>8.0f} {dropped:>13}"
            f" {link.get('oversized', 0):>5} {link.get('protocol_violations', 0):>5}"
            f" {link.get('admissions_deferred', 0):>6} {link.get('chunks_admitted', 0):>6}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=15.0, help="per case")
    parser.add_argument("--cases", default=",".join(CASES),
                        help=f"comma-separated, from {', '.join(CASES)}")
    args = parser.parse_args()
    cases = [name for name in args.cases.split(",") if name]
    unknown = [name for name in cases if name not in CASES]
    if unknown:
        parser.error(f"unknown case(s) {unknown}; known: {', '.join(CASES)}")
    results = {}
    with tempfile.TemporaryDirectory(prefix="warden-flood-") as tmp:
        for name in cases:
            results[name] = run_case(name, args.seconds, Path(tmp))
    print(f"the live cell for {args.seconds:g} s per case (500 Hz; a miss is a tick later than "
          "half a period, or a skipped one)")
    print(f"  {'case':<12} {'ticks':>6} {'misses':>6} {'rate':>7} {'frames/s':>9}"
          f" {'p99 us':>8} {'max us':>8}"
          f" {'jrnl kB/s':>8} {'drop fr/ch':>13} {'>size':>5} {'viol':>5} {'defer':>6}"
          f" {'admit':>6}")
    for name, result in results.items():
        print(_row(name, result, args.seconds))


if __name__ == "__main__":
    main()
