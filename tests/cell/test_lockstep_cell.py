"""The simulated cell on a virtual clock: fast, deterministic, journaled."""

from __future__ import annotations

import asyncio
import json
import re
from pathlib import Path

from kernel.app.lockstep import run_lockstep
from kernel.manifest import ClockKind
from tests.cell.harness import manifest, replays_identically, run_dir


def _run(tmp: Path) -> dict:
    return asyncio.run(run_lockstep(manifest("sim-ur5e.toml", 1, ClockKind.VIRTUAL), tmp))


def test_one_lockstep_cycle_is_verified_and_replays(lockstep_run: Path) -> None:
    """The session's shared lockstep run (tests/conftest.py: ``warden run --clock virtual``)."""
    summary = json.loads((lockstep_run / "summary.json").read_text())
    assert summary["cycles"] == {"attempted": 1, "verified": 1,
                                 "detail": summary["cycles"]["detail"]}
    assert summary["decisions"].get("rejected", 0) < summary["inference_requests"]
    assert summary["proposals_by_phase"]["PRE_CONTACT"] > 5
    assert replays_identically(lockstep_run)


def _without_device_times(journal: Path) -> bytes:
    """The journal, but for the driver's own time stamps (the host's clock, not a decision)."""
    return re.sub(rb',"t_device_ns":\d+', b"", journal.read_bytes())


def test_lockstep_runs_are_byte_identical(tmp_path: Path) -> None:
    """Two runs back to back (not against the session's shared one: the journal's head names
    the checkout's revision, which a commit between the two would change)."""
    _run(tmp_path / "a")
    _run(tmp_path / "b")
    first, second = run_dir(tmp_path / "a"), run_dir(tmp_path / "b")
    assert (first / "decisions.jsonl").read_bytes() == (second / "decisions.jsonl").read_bytes()
    journal = _without_device_times(first / "journal.jsonl")
    assert b'"kind":"command"' in journal
    assert journal == _without_device_times(second / "journal.jsonl")


def test_a_cartesian_policy_completes_a_verified_cycle_that_replays(tmp_path: Path) -> None:
    """The policy proposes TCP displacements; every chunk is mapped through IK in admission."""
    summary = asyncio.run(run_lockstep(
        manifest("sim-ur5e-cartesian.toml", 1, ClockKind.VIRTUAL), tmp_path))
    assert summary["cycles"]["verified"] == 1
    admitted = sum(v for k, v in summary["decisions"].items() if k != "rejected")
    assert admitted > 5
    assert replays_identically(run_dir(tmp_path))
