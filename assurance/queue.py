"""The time-indexed action queue.

Admitted chunks become *segments*: projected rows on the chunk's own action grid, each row due
at ``first_due + row·dt`` and in force until the next row is due. A later segment supersedes an
earlier one from its first due time on, which is what makes replacement atomic: the new tail is
built and projected first, then swapped in by one list operation. Every row remembers the
observation it was conditioned on, so expiry is checked against the client's own clock at the
instant the row would run.
"""

from __future__ import annotations

import msgspec
import numpy as np

from assurance.clock import too_old


class Segment(msgspec.Struct, eq=False):
    chunk_id: str
    epoch: int
    phase: str
    t_obs: int
    expires_at: int
    """First instant at which a row of this segment is too old to run
    (:func:`assurance.clock.expires_at`, computed at admission)."""
    first_due: int
    dt: int
    actions: np.ndarray
    first_index: int
    """Index in the original chunk of row 0 (rows before it were trimmed or cut)."""
    ref_q: np.ndarray
    """The setpoint row 0 follows (the step into row 0 is taken from it, when asked)."""
    rows: int = 0
    end: int = 0
    """``rows`` and the instant the last row stops being due: kept as plain fields (set here and
    by :meth:`truncate`, the only change a segment undergoes) because the queue reads them
    on every tick and every admission."""

    def __post_init__(self) -> None:
        self.rows = int(self.actions.shape[0])
        self.end = self.first_due + self.rows * self.dt

    def truncate(self, rows: int) -> None:
        """Keep only the first ``rows`` rows."""
        self.actions = self.actions[:rows]
        self.rows = rows
        self.end = self.first_due + rows * self.dt

    def due(self, row: int) -> int:
        return self.first_due + row * self.dt

    def too_old(self, t: int) -> bool:
        """Are this segment's rows too old to run at ``t``? (one rule: assurance.clock)"""
        return too_old(t, self.expires_at)

    def row_at(self, t: int) -> int:
        return (t - self.first_due) // self.dt

    def step_into(self, row: int) -> np.ndarray:
        before = self.ref_q if row == 0 else self.actions[row - 1]
        return self.actions[row] - before


class Row(msgspec.Struct, frozen=True, eq=False):
    segment: Segment
    row: int

    @property
    def q(self) -> np.ndarray:
        return self.segment.actions[self.row]

    @property
    def due(self) -> int:
        return self.segment.due(self.row)

    @property
    def chunk_index(self) -> int:
        return self.segment.first_index + self.row


class SentRow(msgspec.Struct, frozen=True, eq=False):
    """A row as it was when a tick sent it: its values, not a view into a segment that a later
    merge may truncate."""

    q: np.ndarray
    step: np.ndarray
    """The step into it from the row before it, on its grid."""
    due: int
    dt: int
    t_obs: int
    """When the observation it was conditioned on was taken."""

    @classmethod
    def of(cls, row: Row) -> SentRow:
        segment = row.segment
        return cls(row.q.copy(), segment.step_into(row.row), row.due, segment.dt, segment.t_obs)


class ActionQueue:
    def __init__(self) -> None:
        self._segments: list[Segment] = []

    def __len__(self) -> int:
        return len(self._segments)

    @property
    def segments(self) -> tuple[Segment, ...]:
        return tuple(self._segments)

    def purge(self) -> int:
        dropped = sum(s.rows for s in self._segments)
        self._segments.clear()
        return dropped

    def pending_rows(self, t: int) -> int:
        """Rows not yet finished at ``t`` (the one in force counts)."""
        total = 0
        segs = self._segments
        for index, seg in enumerate(segs):
            stop = segs[index + 1].first_due if index + 1 < len(segs) else seg.end
            last = min(seg.rows, max(0, -(-(stop - seg.first_due) // seg.dt)))
            done = max(0, min(last, (t - seg.first_due) // seg.dt)) if t >= seg.first_due else 0
            total += last - done
        return total

    def depth_ns(self, t: int) -> int:
        """How long the queue can still feed the controller with rows that will not expire."""
        if not self._segments:
            return 0
        last = self._segments[-1]
        return max(0, min(last.end, last.expires_at) - t)

    def last_end(self) -> int | None:
        return self._segments[-1].end if self._segments else None

    def active(self, t: int) -> Row | None:
        """The row in force at ``t``; finished and superseded segments are dropped first."""
        self._drop_finished(t)
        if not self._segments:
            return None
        head = self._segments[0]
        if t < head.first_due:
            return None
        return Row(head, head.row_at(t))

    def drop_head(self) -> tuple[str, int]:
        """Remove the head segment (its rows expired); returns its chunk id and unrun rows."""
        head = self._segments.pop(0)
        return head.chunk_id, head.rows

    def unrun_rows(self, t: int) -> int:
        head = self._segments[0]
        return head.rows - max(0, head.row_at(t))

    def row_in_force(self, t: int) -> Row | None:
        """The row in force at ``t`` (a later one supersedes it from its first due time on),
        without dropping anything: a question about the future."""
        segs = self._segments
        for index in range(len(segs) - 1, -1, -1):
            seg = segs[index]
            if seg.first_due > t:
                continue
            row = (t - seg.first_due) // seg.dt
            return Row(seg, row) if row < seg.rows else None
        return None

    def predecessor(self, t: int) -> Row | None:
        """The last queued row due strictly before ``t``."""
        segs = self._segments
        for index in range(len(segs) - 1, -1, -1):
            seg = segs[index]
            if seg.first_due >= t:
                continue
            row = min(seg.rows - 1, (t - 1 - seg.first_due) // seg.dt)
            stop = segs[index + 1].first_due if index + 1 < len(segs) else seg.end
            row = min(row, -(-(stop - seg.first_due) // seg.dt) - 1)  # superseded rows
            if row >= 0:
                return Row(seg, row)
        return None

    def value_at(self, t: int) -> np.ndarray | None:
        row = self.predecessor(t + 1)
        if row is None or t >= row.due + row.segment.dt:
            return None
        return row.q

    def rows_from(self, t: int) -> int:
        """Queued rows due at or after ``t`` (what a cut at ``t`` would remove)."""
        total = 0
        for seg in self._segments:
            if seg.end > t:
                total += seg.rows - max(0, min(seg.rows, -(-(t - seg.first_due) // seg.dt)))
        return total

    def obs_time_from(self, t: int) -> int | None:
        """Newest observation time among rows that a chunk starting at ``t`` would displace."""
        times = [s.t_obs for s in self._segments if s.end > t]
        return max(times) if times else None

    def cut_from(self, t: int) -> int:
        """Remove every row due at or after ``t``; returns how many were removed."""
        removed = 0
        kept: list[Segment] = []
        for seg in self._segments:
            if seg.first_due >= t:
                removed += seg.rows
                continue
            keep = min(seg.rows, -(-(t - seg.first_due) // seg.dt))
            removed += seg.rows - keep
            if keep < seg.rows:
                seg.truncate(keep)
            kept.append(seg)
        self._segments = kept
        return removed

    def push(self, segment: Segment) -> None:
        self._segments.append(segment)

    def epochs(self) -> set[int]:
        return {s.epoch for s in self._segments}

    def _drop_finished(self, t: int) -> None:
        segs = self._segments
        while segs and (segs[0].end <= t or (len(segs) > 1 and segs[1].first_due <= t)):
            segs.pop(0)
