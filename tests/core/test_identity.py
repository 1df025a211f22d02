"""Identity memory (duplicates vs conflicts, bounded, survives reconnection) and the
observation log."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from assurance.identity import ChunkMemory, ObservationLog, Seen


def test_unknown_id_is_new() -> None:
    assert ChunkMemory().classify("c1", "h1") is Seen.NEW


def test_same_id_same_hash_is_a_duplicate() -> None:
    memory = ChunkMemory()
    memory.remember("c1", "h1")
    assert memory.classify("c1", "h1") is Seen.DUPLICATE


def test_same_id_other_hash_is_a_conflict_and_never_overwrites() -> None:
    memory = ChunkMemory()
    memory.remember("c1", "h1")
    assert memory.classify("c1", "h2") is Seen.CONFLICT
    memory.remember("c1", "h2")
    assert memory.classify("c1", "h1") is Seen.DUPLICATE
    assert memory.classify("c1", "h2") is Seen.CONFLICT
    assert len(memory) == 1


def test_memory_is_bounded_and_forgets_the_oldest_first() -> None:
    memory = ChunkMemory(capacity=3)
    for i in range(5):
        memory.remember(f"c{i}", f"h{i}")
    assert len(memory) == 3
    assert memory.classify("c0", "h0") is Seen.NEW
    assert memory.classify("c1", "h1") is Seen.NEW
    assert [memory.classify(f"c{i}", f"h{i}") for i in (2, 3, 4)] == [Seen.DUPLICATE] * 3


@given(st.lists(st.integers(0, 30), max_size=60), st.integers(1, 8))
def test_memory_keeps_exactly_the_most_recent_distinct_ids(ids: list[int], capacity: int) -> None:
    memory = ChunkMemory(capacity)
    order: list[int] = []
    for i in ids:
        memory.remember(str(i), "h")
        if i not in order:
            order.append(i)
        order = order[-capacity:]
    assert len(memory) == len(order)
    for i in range(31):
        expected = Seen.DUPLICATE if i in order else Seen.NEW
        assert memory.classify(str(i), "h") is expected


def test_memory_survives_simulated_reconnections() -> None:
    """The caller never clears it: a resend after reconnect (new epoch) is still known."""
    memory = ChunkMemory()
    memory.remember("c1", "h1")
    log = ObservationLog()
    log.record("o1", 10)
    log.clear()  # the session ended (link lost); chunk memory stays
    memory.remember("c2", "h2")
    assert memory.classify("c1", "h1") is Seen.DUPLICATE
    assert memory.classify("c1", "hX") is Seen.CONFLICT


@pytest.mark.parametrize("capacity", [0, -1])
def test_capacity_must_be_positive(capacity: int) -> None:
    with pytest.raises(ValueError):
        ChunkMemory(capacity)


# --- observation log ---------------------------------------------------------------------------


def test_observation_log_records_times_and_latest() -> None:
    log = ObservationLog()
    assert log.time_of("o1") is None and log.latest is None
    log.record("o1", 100)
    log.record("o2", 200)
    assert log.time_of("o1") == 100 and log.time_of("o2") == 200
    assert log.latest == "o2"


def test_observation_log_is_bounded_oldest_first() -> None:
    log = ObservationLog(capacity=2)
    log.record("o1", 1)
    log.record("o2", 2)
    log.record("o1", 3)  # re-recorded: now the newest
    log.record("o3", 4)
    assert log.time_of("o2") is None
    assert log.time_of("o1") == 3 and log.time_of("o3") == 4


def test_observation_log_clear_forgets_the_session() -> None:
    log = ObservationLog()
    log.record("o1", 100)
    log.clear()
    assert log.time_of("o1") is None and log.latest is None


def test_an_observation_is_pending_until_an_admitted_chunk_answers_it() -> None:
    log = ObservationLog(capacity=2)
    log.answer("never-sent")  # nothing to answer: stays unknown, not answered
    assert not log.answered("never-sent")
    log.record("o1", 1)
    assert not log.answered("o1")
    log.answer("o1")
    assert log.answered("o1") and log.time_of("o1") == 1
    log.record("o2", 2)
    log.record("o3", 3)  # o1 is forgotten: an answer to it is an unknown observation again
    assert not log.answered("o1") and log.time_of("o1") is None
    log.answer("o3")
    log.forget_answers()  # a new epoch purged the answer: o3 is pending again, still known
    assert not log.answered("o3") and log.time_of("o3") == 3
    log.answer("o3")
    log.clear()  # a new session: nothing of the old one is pending or answered
    assert not log.answered("o3") and log.time_of("o3") is None
