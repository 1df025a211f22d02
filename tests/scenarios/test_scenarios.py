"""Every scenario in manifests/scenarios/ replays, meets its expectations, deterministically."""

from __future__ import annotations

import functools
from pathlib import Path

import msgspec
import pytest

from kernel.replay import check_expectations, replay_bytes
from kernel.scenario.load import load_scenario
from tools.scenarios.catalog import all_documents

ROOT = Path(__file__).resolve().parents[2]
SCENARIO_DIR = ROOT / "manifests" / "scenarios"
FILES = sorted(SCENARIO_DIR.glob("*.json"))


@functools.cache
def _replayed(path: Path) -> bytes:
    """A scenario's decision log, replayed once for every test of this module that reads it
    (the byte-identity test replays a second time, from a fresh load, to compare)."""
    return replay_bytes(load_scenario(path))


def test_catalog_has_scenarios() -> None:
    assert len(FILES) >= 40


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.stem)
def test_scenario_meets_its_expectations(path: Path) -> None:
    scenario = load_scenario(path)
    assert scenario.expect, "a scenario without expectations proves nothing"
    lines = [msgspec.json.decode(line) for line in _replayed(path).splitlines()]
    assert check_expectations(scenario, lines) == []


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.stem)
def test_replay_is_byte_identical(path: Path) -> None:
    first = _replayed(path)
    second = replay_bytes(load_scenario(path))
    assert first == second


def test_committed_files_match_the_catalog() -> None:
    generated = all_documents()
    committed = {p.stem: p.read_text(encoding="utf-8") for p in FILES}
    assert sorted(generated) == sorted(committed), "run `python -m tools.scenarios`"
    stale = [name for name, text in generated.items() if committed[name] != text]
    assert stale == [], f"out of date, run `python -m tools.scenarios`: {stale}"


def _reasons_in_logs() -> set[str]:
    seen: set[str] = set()
    for path in FILES:
        for raw in _replayed(path).splitlines():
            line = msgspec.json.decode(raw)
            seen.update(line.get("reasons", ()))
            for key in ("trigger", "reason"):
                if line.get(key):
                    seen.add(line[key])
    return seen


def test_every_contract_reason_code_is_exercised() -> None:
    from assurance.reasons import CONTRACT_CODES

    missing = sorted(code for code in CONTRACT_CODES if code not in _reasons_in_logs())
    assert missing == []


def test_every_fallback_state_is_reached() -> None:
    from assurance.fallback import Mode

    reached: set[str] = set()
    for path in FILES:
        for raw in _replayed(path).splitlines():
            line = msgspec.json.decode(raw)
            if line["kind"] == "transition" and line["machine"] == "fallback":
                reached.add(line["to"])
    assert reached >= {mode.value for mode in Mode}
