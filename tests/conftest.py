"""Shared test configuration: hypothesis profiles sized for a 2-core CI machine, and the one
recorded lockstep run the tests that read a run's record share."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile(
    "ci", deadline=None, max_examples=60, suppress_health_check=[HealthCheck.too_slow]
)
settings.register_profile("thorough", deadline=None, max_examples=1000)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


@pytest.fixture(scope="session")
def lockstep_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One run of the shipped simulated cell on the virtual clock, journaled, as
    ``warden run --clock virtual --cycles 1`` records it: its run directory (journal.jsonl,
    decisions.jsonl, summary.json). One run for every test that only reads such a record (a
    whole cycle is seconds of CPU); a test that changes it works on a copy."""
    from kernel.cli import main

    root = tmp_path_factory.mktemp("lockstep-run")
    assert main(["run", "--clock", "virtual", "--cycles", "1", "--journal-dir", str(root)]) == 0
    (directory,) = root.iterdir()
    return directory
