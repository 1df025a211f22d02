"""Shared test configuration: hypothesis profiles sized for a 2-core CI machine, each test's
own logging configuration, and the one recorded lockstep run the tests that read a run's
record share."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest
import structlog
from hypothesis import HealthCheck, settings

# Offscreen rendering (stubs/plant/cameras.py) needs EGL chosen before anything imports MuJoCo.
os.environ.setdefault("MUJOCO_GL", "egl")

settings.register_profile(
    "ci", deadline=None, max_examples=60, suppress_health_check=[HealthCheck.too_slow]
)
settings.register_profile("thorough", deadline=None, max_examples=1000)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


WALL_CLOCK_RERUNS = 1
"""A test marked ``slow`` runs a cell, an emulator or a monitor against the wall clock; on the
shared 2-core test machine the host's own load (its loop benchmark measured a timerfd p99 of
1.5 ms and 2.6 % CPU steal in one hour, 0.3 ms in another) can starve one run into a refusal
it would not make on a robot PC. Such a test runs once more after a failure, and only then
fails; pytest's summary lists every rerun (``R``), so a flaky test stays visible."""


WALL_CLOCK_DIRS = frozenset({"cell", "cli", "conformance", "drivers", "interop", "ops",
                             "safety", "shell", "wire"})
"""The test directories whose tests run cells, devices, emulators, links, timers or services
against the wall clock (with every test marked ``slow``): the ``wall-clock`` set of
``make test``, run alone, after the ``in-process`` set (every other test), which runs on both
cores at once (the Makefile says how)."""


def wall_clock(item: pytest.Item) -> bool:
    relative = item.path.relative_to(Path(__file__).parent)
    return (item.get_closest_marker("slow") is not None
            or (len(relative.parts) > 1 and relative.parts[0] in WALL_CLOCK_DIRS))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("slow") is not None:
            item.add_marker(pytest.mark.flaky(reruns=WALL_CLOCK_RERUNS))
    chosen = os.environ.get("WARDEN_TEST_SET")
    if chosen is None:
        return
    if chosen not in ("wall-clock", "in-process"):
        raise pytest.UsageError(f"WARDEN_TEST_SET={chosen!r}: expected wall-clock or in-process")
    keep = [item for item in items if wall_clock(item) == (chosen == "wall-clock")]
    config.hook.pytest_deselected(items=[item for item in items if item not in keep])
    items[:] = keep


@pytest.fixture(autouse=True)
def _logging_as_the_suite_began() -> Iterator[None]:
    """Whatever a test's in-process command configured (``warden check`` logs at WARNING) ends
    with the test: ``structlog.testing.capture_logs`` swaps the processors, not the level, and
    a WARNING level left behind by one test hid the INFO lines a later test asserted
    (tests/safety/test_canopen_watch.py's EMCY test failed so in the suite, never alone)."""
    saved = structlog.get_config()
    yield
    structlog.configure(**saved)


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
