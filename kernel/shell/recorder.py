"""The run recorder: the journal (events) and the decision log (lines) written off the tick path.

The control tick only appends already-encoded lines to in-memory buffers; every
``flush_interval_s`` the recorder task swaps the buffers out and queues them for its own writer
thread (one write per file), so a slow or stalled disk delays the recorder, never the event loop
the controller runs on. The writer never calls back into the loop: with ``run_in_executor``
instead, the CANopen cell lost drive heartbeats at start-up in most runs on the 2-core test
machine (the mechanism was not pinned down; this design does not show it). The buffers, queued
batches included, are bounded: if the recorder falls that far behind, the overflow is counted as
a gap and reported (a journal with a gap is not promoted as a replay of the run), and the run
goes on holding the safety decisions in the decision log it could still write.
"""

from __future__ import annotations

import asyncio
import json
import os
import queue
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from kernel.core.events import Event
from kernel.core.lines import Line, encode
from kernel.journal import CommandRecord, command_line, event_record


@dataclass
class RecorderStats:
    events: int = 0
    lines: int = 0
    gaps: int = 0
    flushes: int = 0
    error: str | None = None
    """The first write error (exception type and errno text); everything after it is a gap."""


class RecorderError(RuntimeError):
    """The journal or the decision log could not be written: the run's record is incomplete."""


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
        self._batches: queue.SimpleQueue[_Batch | None] = queue.SimpleQueue()
        self._queued = 0  # items handed over and not yet written (the bound covers them too)
        self._queued_lock = threading.Lock()
        self._failure: BaseException | None = None
        self._writer = threading.Thread(target=self._write_batches, name="warden-recorder",
                                        daemon=True)
        self._writer.start()
        if journal is not None and head is not None:
            journal.write(json.dumps(dict(head), allow_nan=True) + "\n")

    def event(self, event: Event) -> None:
        if self._journal is None:
            return
        if len(self._events) + self._queued >= self._max:
            self._count_gap(1)
            return
        self._events.append(json.dumps(event_record(event), allow_nan=True))
        self.stats.events += 1

    def command(self, record: CommandRecord) -> None:
        """A command as written to the driver, with its answer (a journal line like an event)."""
        if self._journal is None:
            return
        if len(self._events) + self._queued >= self._max:
            self._count_gap(1)
            return
        self._events.append(command_line(record).decode())
        self.stats.events += 1

    def lines(self, lines: tuple[Line, ...] | list[Line]) -> None:
        if self._decisions is None or not lines:
            return
        if len(self._lines) + self._queued >= self._max:
            self._count_gap(len(lines))
            return
        self._lines.extend(encode(line) for line in lines)
        self.stats.lines += len(lines)

    def hand_over(self) -> None:
        """Pass what is buffered to the writer thread; never waits for the disk.

        Raises:
            RecorderError: an earlier write failed (the recorder task is critical: the run
                ends, holding the arm, rather than go on with a record that has a hole).
        """
        if self._failure is not None:
            self._count_gap(len(self._events) + len(self._lines))  # never to be written
            self._events, self._lines = [], []
            raise RecorderError(f"cannot write the run record: {self.stats.error}") from (
                self._failure)
        if self._events or self._lines:
            with self._queued_lock:
                self._queued += len(self._events) + len(self._lines)
            self._batches.put(_Batch(self._events, self._lines, None))
            self._events, self._lines = [], []
            self.stats.flushes += 1

    def flush(self) -> None:
        """Write everything buffered so far and wait until it is on its way to disk (end of a
        run, lockstep runs)."""
        try:
            self.hand_over()
        except RecorderError:
            return  # nothing more will be written; the error is in stats
        written = threading.Event()
        self._batches.put(_Batch([], [], written))
        while not written.wait(0.5):
            if not self._writer.is_alive():
                return

    def close(self) -> None:
        """Flush, then stop the writer thread; the files stay open (their owner closes them)."""
        if not self._writer.is_alive():
            return
        self.flush()
        self._batches.put(None)
        self._writer.join()

    async def run(self, started: Any = None) -> None:
        """Hand the buffers over periodically until cancelled (the last hand-over is
        :meth:`close`'s). Raises :class:`RecorderError` once a write has failed.

        Nothing from the writer thread ever calls back into the event loop: the loop only
        puts batches on a queue, the thread only takes them off.
        """
        if started is not None:
            started()
        while True:
            await asyncio.sleep(self.flush_interval_s)
            self.hand_over()

    def _write_batches(self) -> None:
        _ordinary_priority()
        while (batch := self._batches.get()) is not None:
            count = len(batch.events) + len(batch.lines)
            try:
                if self._failure is None:
                    self._write(batch)
                else:
                    self._count_gap(count)
            except Exception as error:  # a full or failing disk: record it, never die
                self._failure = error
                self.stats.error = f"{type(error).__name__}: {error}"
                self._count_gap(count)
            finally:
                with self._queued_lock:
                    self._queued -= count
                if batch.written is not None:
                    batch.written.set()

    def _write(self, batch: _Batch) -> None:
        if self._journal is not None and batch.events:
            self._journal.write("\n".join(batch.events) + "\n")
            self._journal.flush()
        if self._decisions is not None and batch.lines:
            self._decisions.write(b"\n".join(batch.lines) + b"\n")
            self._decisions.flush()

    def _count_gap(self, count: int) -> None:
        with self._queued_lock:  # stats are also counted on the loop thread
            self.stats.gaps += count


@dataclass(frozen=True, slots=True)
class _Batch:
    events: list[str]
    lines: list[bytes]
    written: threading.Event | None
    """Set once this batch (and everything queued before it) has been written."""


def _ordinary_priority() -> None:
    """Disk writes never compete with a real-time control loop: whatever policy the creating
    thread had, the writer runs with the ordinary one (Linux applies this per thread)."""
    if os.sched_getscheduler(0) != os.SCHED_OTHER:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def open_run_files(directory: Path, name: str) -> tuple[Path, IO[str], IO[bytes]]:
    """A fresh run directory with ``journal.jsonl`` and ``decisions.jsonl``."""
    directory.mkdir(parents=True, exist_ok=True)
    index = 1 + max((int(p.name.rsplit("-", 1)[-1]) for p in directory.glob(f"{name}-*")
                     if p.name.rsplit("-", 1)[-1].isdigit()), default=0)
    run_dir = directory / f"{name}-{index:04d}"
    run_dir.mkdir()
    return (run_dir, (run_dir / "journal.jsonl").open("w", encoding="utf-8"),
            (run_dir / "decisions.jsonl").open("wb"))
