"""The run recorder: the journal (events) and the decision log (lines) written off the tick path.

The control tick only appends already-encoded lines to in-memory buffers; a recorder task
writes them out every ``flush_interval_s`` with one write per file, so a slow disk delays the
recorder, never the controller. The buffers are bounded: if the recorder falls that far behind,
the overflow is counted as a gap and reported (a journal with a gap is not promoted as a replay
of the run), and the run goes on holding the safety decisions in the decision log it could
still write.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from kernel.core.events import Event
from kernel.core.lines import Line, encode
from kernel.journal import event_record


@dataclass
class RecorderStats:
    events: int = 0
    lines: int = 0
    gaps: int = 0
    flushes: int = 0


class Recorder:
    def __init__(
        self, journal: IO[str] | None, decisions: IO[bytes] | None,
        head: Mapping[str, Any] | None = None, max_buffered: int = 200_000,
        flush_interval_s: float = 0.05,
    ) -> None:
        self._journal, self._decisions = journal, decisions
        self._events: list[str] = []
        self._lines: list[bytes] = []
        self._max = max_buffered
        self.flush_interval_s = flush_interval_s
        self.stats = RecorderStats()
        if journal is not None and head is not None:
            journal.write(json.dumps(dict(head), allow_nan=True) + "\n")

    def event(self, event: Event) -> None:
        if self._journal is None:
            return
        if len(self._events) >= self._max:
            self.stats.gaps += 1
            return
        self._events.append(json.dumps(event_record(event), allow_nan=True))
        self.stats.events += 1

    def lines(self, lines: list[Line]) -> None:
        if self._decisions is None or not lines:
            return
        if len(self._lines) >= self._max:
            self.stats.gaps += len(lines)
            return
        self._lines.extend(encode(line) for line in lines)
        self.stats.lines += len(lines)

    def flush(self) -> None:
        if self._journal is not None and self._events:
            self._journal.write("\n".join(self._events) + "\n")
            self._events.clear()
            self._journal.flush()
        if self._decisions is not None and self._lines:
            self._decisions.write(b"\n".join(self._lines) + b"\n")
            self._lines.clear()
            self._decisions.flush()
        self.stats.flushes += 1

    async def run(self, started: Any = None) -> None:
        """Flush periodically until cancelled; the final flush happens in ``finally``."""
        if started is not None:
            started()
        try:
            while True:
                await asyncio.sleep(self.flush_interval_s)
                self.flush()
        finally:
            self.flush()


def open_run_files(directory: Path, name: str) -> tuple[Path, IO[str], IO[bytes]]:
    """A fresh run directory with ``journal.jsonl`` and ``decisions.jsonl``."""
    directory.mkdir(parents=True, exist_ok=True)
    index = 1 + max((int(p.name.rsplit("-", 1)[-1]) for p in directory.glob(f"{name}-*")
                     if p.name.rsplit("-", 1)[-1].isdigit()), default=0)
    run_dir = directory / f"{name}-{index:04d}"
    run_dir.mkdir()
    return (run_dir, (run_dir / "journal.jsonl").open("w", encoding="utf-8"),
            (run_dir / "decisions.jsonl").open("wb"))
