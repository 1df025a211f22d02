"""A journal replays what the run fed its core, to the nanosecond."""

from __future__ import annotations

from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from kernel.core.events import ClockSyncEvent
from kernel.journal import JournalWriter, header
from kernel.manifest import load_manifest
from kernel.scenario.events import MAX_NS
from kernel.scenario.load import load_scenario

MANIFEST = Path(__file__).resolve().parents[2] / "manifests" / "sim-ur5e.toml"
SECTIONS = load_manifest(MANIFEST).sections.document()


@settings(max_examples=60, deadline=None)
@given(offset=st.integers(-MAX_NS, MAX_NS), round_trip=st.integers(0, MAX_NS))
def test_clock_sync_offsets_round_trip_exactly(
        tmp_path_factory, offset: int, round_trip: int) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path_factory.mktemp("journal") / "journal.jsonl"
    event = ClockSyncEvent(t=3_000_000, domain="server", offset=offset, round_trip=round_trip)
    with path.open("w", encoding="utf-8") as stream:
        JournalWriter(stream, header(SECTIONS, "roundtrip")).write(event)
    (loaded,) = [e for e in load_scenario(path).events if isinstance(e, ClockSyncEvent)]
    assert (loaded.offset, loaded.round_trip) == (offset, round_trip)
