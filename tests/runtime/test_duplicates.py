"""Property: any number of duplicates changes nothing but their own 'ignored' lines."""

from __future__ import annotations

from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from kernel.core.events import ChunkEvent
from kernel.core.lines import encode
from kernel.core.runtime import Core
from kernel.scenario.load import Scenario, load_scenario
from tests.runtime.machine_setup import feed

ROOT = Path(__file__).resolve().parents[2] / "manifests" / "scenarios"
BASES = [load_scenario(ROOT / f"{name}.json") for name in (
    "seed_stale_chunk", "replace_atomic", "network_faults_free_space", "trimmed_free_space",
    "human_takeover_and_release",
)]


def _log(scenario: Scenario, extra: list[ChunkEvent]) -> list[bytes]:
    events = sorted([*scenario.events, *extra], key=lambda e: e.t)  # stable: originals first
    variant = Scenario(scenario.name, scenario.path, scenario.config, events,
                       scenario.until_ns, scenario.recorded_ticks)
    core = Core(variant.config)
    return [encode(line) for event in variant.timeline() for line in feed(core, event)]


@st.composite
def duplicated(draw: st.DrawFn) -> tuple[Scenario, list[ChunkEvent]]:
    scenario = draw(st.sampled_from(BASES))
    originals = [e for e in scenario.events
                 if isinstance(e, ChunkEvent) and hasattr(e.chunk, "payload_hash")]
    picks = draw(st.lists(st.sampled_from(originals), min_size=1, max_size=8))
    extra = []
    for original in picks:
        delay_ns = draw(st.integers(1, 200)) * 1_000_000 + draw(st.integers(0, 999_999))
        extra.append(ChunkEvent(original.t + delay_ns, original.chunk))
    return scenario, extra


@given(duplicated())
def test_duplicates_change_nothing(case: tuple[Scenario, list[ChunkEvent]]) -> None:
    scenario, extra = case
    baseline = _log(scenario, [])
    with_duplicates = _log(scenario, extra)
    ignored = [line for line in with_duplicates
               if b'"decision":"ignored"' in line and b'"DUPLICATE"' in line]
    kept = [line for line in with_duplicates if line not in ignored]
    assert kept == [line for line in baseline if line not in ignored]
    assert len(with_duplicates) - len(kept) >= len(extra)
