"""The time-indexed action queue: atomic replacement, the row in force, depth and purge."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from assurance.queue import ActionQueue, Segment

DT = 10


def seg(chunk_id: str, first_due: int, rows: int, dt: int = DT, t_obs: int = 0,
        expires_at: int = 10**9, base: float = 0.0) -> Segment:
    actions = base + np.arange(rows, dtype=float)[:, None] * np.ones((1, 2))
    return Segment(chunk_id=chunk_id, epoch=1, phase="FREE_SPACE", t_obs=t_obs,
                   expires_at=expires_at, first_due=first_due, dt=dt, actions=actions,
                   first_index=0, ref_q=np.zeros(2))


def queue_of(*segments: Segment) -> ActionQueue:
    queue = ActionQueue()
    for s in segments:
        queue.push(s)
    return queue


def due_rows(queue: ActionQueue) -> list[tuple[str, int, float]]:
    """(chunk id, due time, first value) of every stored row."""
    return [(s.chunk_id, s.due(r), float(s.actions[r, 0])) for s in queue.segments
            for r in range(s.rows)]


segments_st = st.lists(
    st.tuples(st.integers(0, 200), st.integers(1, 12), st.sampled_from([5, 10, 20])),
    min_size=1, max_size=4,
)


@given(segments_st, st.integers(-20, 300), st.integers(1, 10))
def test_replacement_is_atomic(spec: list[tuple[int, int, int]], cut: int, new_rows: int) -> None:
    queue = queue_of(*(seg(f"old{i}", fd, n, dt) for i, (fd, n, dt) in enumerate(spec)))
    before = due_rows(queue)
    removed = queue.cut_from(cut)
    queue.push(seg("new", cut, new_rows, base=100.0))
    old_after = [row for row in due_rows(queue) if row[0] != "new"]
    assert all(due < cut for _, due, _ in old_after)
    assert old_after == [row for row in before if row[1] < cut]
    assert removed == len(before) - len(old_after)


@given(segments_st, st.integers(0, 300), st.integers(0, 400))
def test_after_a_swap_only_the_new_rows_are_in_force_from_the_cut(
    spec: list[tuple[int, int, int]], cut: int, t: int
) -> None:
    queue = queue_of(*(seg(f"old{i}", fd, n, dt) for i, (fd, n, dt) in enumerate(spec)))
    queue.cut_from(cut)
    queue.push(seg("new", cut, 5, base=100.0))
    row = queue.active(t)
    if cut <= t < cut + 5 * DT:
        assert row is not None and row.segment.chunk_id == "new"
        assert row.row == (t - cut) // DT and row.q[0] == 100.0 + row.row
    elif t >= cut:
        assert row is None  # the new chunk finished; nothing old comes back
    elif row is not None:
        assert row.segment.chunk_id != "new" and row.due <= t < row.due + row.segment.dt


def test_active_returns_the_row_in_force() -> None:
    queue = queue_of(seg("a", 100, 3))
    assert queue.active(99) is None  # not started yet
    row = queue.active(115)
    assert row is not None and row.row == 1 and row.due == 110 and row.chunk_index == 1
    assert queue.active(129).row == 2
    assert queue.active(130) is None  # finished
    assert len(queue) == 0  # and dropped


def test_superseded_segment_is_dropped_once_the_next_starts() -> None:
    queue = queue_of(seg("a", 0, 10), seg("b", 50, 3))
    assert queue.active(49).segment.chunk_id == "a"
    assert queue.active(50).segment.chunk_id == "b"
    assert [s.chunk_id for s in queue.segments] == ["b"]


def test_pending_rows_counts_the_row_in_force_and_stops_at_the_next_segment() -> None:
    queue = queue_of(seg("a", 0, 10), seg("b", 50, 3))
    assert queue.pending_rows(0) == 5 + 3  # a runs rows 0..4 before b takes over
    assert queue.pending_rows(25) == 3 + 3  # rows 2 (in force), 3, 4 of a
    assert queue.pending_rows(60) == 2  # b row 1 in force, row 2 to come
    assert queue.pending_rows(80) == 0
    assert ActionQueue().pending_rows(0) == 0


def test_depth_is_bounded_by_the_end_and_by_expiry() -> None:
    assert ActionQueue().depth_ns(0) == 0
    assert queue_of(seg("a", 0, 10)).depth_ns(30) == 70
    assert queue_of(seg("a", 0, 10, expires_at=50)).depth_ns(30) == 20
    assert queue_of(seg("a", 0, 10)).depth_ns(500) == 0


def test_a_segment_is_too_old_from_its_expiry_instant_on() -> None:
    """The rule of assurance.clock: valid up to expires_at − 1 ns, too old at expires_at."""
    long_tail = seg("a", 0, 10, expires_at=45)  # rows due 0..90, young enough until 44
    assert not long_tail.too_old(44) and long_tail.too_old(45) and long_tail.too_old(90)
    assert queue_of(long_tail).active(44).row == 4  # the row in force is still young ...
    assert long_tail.too_old(45)  # ... and the same row is too old 1 ns later
    assert queue_of(long_tail).depth_ns(44) == 1


def test_purge_empties_and_counts() -> None:
    queue = queue_of(seg("a", 0, 4), seg("b", 100, 3))
    assert queue.purge() == 7
    assert len(queue) == 0 and queue.active(0) is None and queue.last_end() is None


def test_cut_before_every_segment_removes_all() -> None:
    queue = queue_of(seg("a", 10, 4), seg("b", 100, 3))
    assert queue.cut_from(10) == 7 and len(queue) == 0


def test_predecessor_and_value_at() -> None:
    queue = queue_of(seg("a", 0, 5))
    assert queue.predecessor(0) is None
    assert queue.predecessor(25).row == 2
    assert queue.predecessor(1000).row == 4
    assert queue.value_at(25)[0] == 2.0
    assert queue.value_at(49)[0] == 4.0
    assert queue.value_at(50) is None  # after the end nothing is in force


def test_predecessor_skips_rows_superseded_by_a_later_segment() -> None:
    queue = queue_of(seg("a", 0, 10), seg("b", 100, 3))
    row = queue.predecessor(95)
    assert row.segment.chunk_id == "a" and row.row == 9
    queue2 = queue_of(seg("a", 0, 10), seg("b", 45, 3))
    assert queue2.predecessor(45).row == 4  # rows 5.. of a never run


def test_observation_time_of_rows_a_new_chunk_would_displace() -> None:
    queue = queue_of(seg("a", 0, 5, t_obs=7), seg("b", 50, 5, t_obs=3))
    assert queue.obs_time_from(10) == 7
    assert queue.obs_time_from(60) == 3
    assert queue.obs_time_from(100) is None


def test_drop_head_and_unrun_rows() -> None:
    queue = queue_of(seg("a", 0, 5), seg("b", 50, 2))
    assert queue.unrun_rows(20) == 3
    assert queue.drop_head() == ("a", 5)
    assert [s.chunk_id for s in queue.segments] == ["b"]
    assert queue.epochs() == {1}
