"""Real-time chunking in the simulated cell: the reference server as a process offers it
(``[policy] rtc = true``), warden sends the committed prefix with each observation, the
conditioned answers carry the approach to a verified insertion, and the journal (prefixes
included) replays exactly."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import msgspec
import pytest

from kernel.app.live import run_live
from kernel.shell.loop import run
from tests.cell.harness import manifest, replays_identically, run_dir

pytestmark = pytest.mark.slow


def test_a_cycle_driven_by_conditioned_chunks_is_verified_and_replays(tmp_path: Path) -> None:
    loaded = manifest("sim-ur5e.toml", cycles=1)
    rtc = msgspec.structs.replace(loaded.policy, rtc=True)
    summary = run(run_live(dataclasses.replace(loaded, policy=rtc), tmp_path / "runs"))
    directory = run_dir(tmp_path / "runs")
    assert summary["cycles"]["verified"] == 1, summary["cycles"]
    journal = [json.loads(line) for line in (directory / "journal.jsonl").read_text().splitlines()
               if line.startswith("{")]
    prefixes = [e["rtc"] for e in journal if e.get("kind") == "observation" and "rtc" in e]
    assert len(prefixes) >= 5
    decisions = [json.loads(line) for line in (directory / "decisions.jsonl").read_text()
                 .splitlines()]
    chunks = [d for d in decisions if d.get("kind") == "chunk"]
    # The server reproduces the prefix exactly. An answer that arrives after the task left the
    # phase (PHASE_MISMATCH) finds the queue purged since its prefix was taken, and says so.
    current = [d for d in chunks if "PHASE_MISMATCH" not in d["reasons"]]
    assert not [d for d in current if "RTC_PREFIX_MISMATCH" in d["reasons"]]
    # PRE_CONTACT forbids trimming: every trimmed chunk there dropped only committed actions.
    assert sum(d["decision"] == "trimmed" for d in chunks) >= 5
    assert replays_identically(directory)
