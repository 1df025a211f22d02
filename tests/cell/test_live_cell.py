"""The simulated cell on the wall clock, with the policy server as a process and a real
websocket between them: the live decisions are exactly what the journal replays."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from kernel.cell.live import run_live
from kernel.shell.loop import run
from tests.cell.harness import manifest, replays_identically, run_dir

pytestmark = pytest.mark.slow


def test_live_cycle_over_the_websocket_replays_exactly(tmp_path: Path) -> None:
    summary = run(run_live(manifest("sim-ur5e.toml", cycles=1), tmp_path))
    assert summary["cycles"]["attempted"] == 1
    link = summary["link"]
    assert link["handshakes_accepted"] >= 1
    assert link["chunks_admitted"] > 5
    assert summary["loop"]["ticks"] > 1000
    directory = run_dir(tmp_path)
    assert replays_identically(directory)
    saved = json.loads((directory / "summary.json").read_text())
    assert saved["cycles"]["attempted"] == 1
