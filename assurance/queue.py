"""The time-indexed action queue (seed §3.2).

Admitted chunks become *segments*: projected rows on the chunk's own action grid, each row due
at ``first_due + row·dt`` and in force until the next row is due. A later segment supersedes an
earlier one from its first due time on, which is what makes replacement atomic: the new tail is
built and projected first, then swapped in by one list operation. Every row remembers the
observation it was conditioned on, so expiry is checked against the client's own clock at the
instant the row would run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(slots=True, eq=False)
class Segment:
    chunk_id: str
    epoch: int
    phase: str
    t_obs: int
    expires_at: int
    """First instant at which a row of this segment is too old to run (age bound − uncertainty)."""
    first_due: int
    dt: int
    actions: np.ndarray
    first_index: int
    """Index in the original chunk of row 0 (rows before it were trimmed or cut)."""
    ref_step: np.ndarray
    """Step from the preceding setpoint to row 0, on this segment's grid."""

    @property
    def rows(self) -> int:
        return int(self.actions.shape[0])

    @property
    def end(self) -> int:
        return self.first_due + self.rows * self.dt

    def due(self, row: int) -> int:
        return self.first_due + row * self.dt

    def row_at(self, t: int) -> int:
        return (t - self.first_due) // self.dt

    def step_into(self, row: int) -> np.ndarray:
        return self.ref_step if row == 0 else self.actions[row] - self.actions[row - 1]


@dataclass(frozen=True, slots=True, eq=False)
class Row:
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
        for index, seg in enumerate(self._segments):
            stop = self._cut_of(index)
            last = min(seg.rows, max(0, -(-(stop - seg.first_due) // seg.dt)))
            done = max(0, min(last, seg.row_at(t))) if t >= seg.first_due else 0
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

    def predecessor(self, t: int) -> Row | None:
        """The last queued row due strictly before ``t``."""
        for index in range(len(self._segments) - 1, -1, -1):
            seg = self._segments[index]
            if seg.first_due >= t:
                continue
            row = min(seg.rows - 1, (t - 1 - seg.first_due) // seg.dt)
            stop = self._cut_of(index)
            while row >= 0 and seg.due(row) >= stop:
                row -= 1
            if row >= 0:
                return Row(seg, row)
        return None

    def value_at(self, t: int) -> np.ndarray | None:
        row = self.predecessor(t + 1)
        if row is None or t >= row.due + row.segment.dt:
            return None
        return row.q

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
                seg.actions = seg.actions[:keep]
            kept.append(seg)
        self._segments = kept
        return removed

    def push(self, segment: Segment) -> None:
        self._segments.append(segment)

    def epochs(self) -> set[int]:
        return {s.epoch for s in self._segments}

    def _cut_of(self, index: int) -> int:
        """Where segment ``index`` stops being in force: the next segment's first due time."""
        if index + 1 < len(self._segments):
            return self._segments[index + 1].first_due
        return self._segments[index].end

    def _drop_finished(self, t: int) -> None:
        segs = self._segments
        while segs and (segs[0].end <= t or (len(segs) > 1 and segs[1].first_due <= t)):
            segs.pop(0)
