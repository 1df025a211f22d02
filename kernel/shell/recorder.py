"""The run recorder: the journal (events) and the decision log (lines) written off the tick path.

The control tick only appends already-encoded lines to in-memory buffers; every
``flush_interval_s`` the recorder task swaps the buffers out and queues them for its own writer
thread, so a slow or stalled disk delays the recorder, never the event loop the controller runs
on. The writer never calls back into the loop: with ``run_in_executor`` instead, the CANopen
cell lost drive heartbeats at start-up in most runs on the 2-core test machine (the mechanism
was not pinned down; this design does not show it). The buffers, queued batches included, are
bounded: if the recorder falls that far behind, the overflow is counted as a gap and reported (a
journal with a gap is not promoted as a replay of the run).

A write that fails (a full, failing or read-only disk: :mod:`kernel.shell.record_file`) is not
the recorder's to handle alone: it sets :attr:`Recorder.fault`, which the control loop turns
into a ``recorder`` event for the core (RECORDER_FAILED: the core stops the arm) before the
run ends. Nothing more is written in the files' normal course; what the run records from the
failing batch on is kept and written, at :meth:`Recorder.close`, into the space each file keeps
reserved, all of it or (if it does not fit) none, so both files stay whole prefixes of the run.
"""

from __future__ import annotations

import asyncio
import json
import queue
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from kernel.core.events import Event, RecorderFault
from kernel.core.lines import Line, encode
from kernel.journal import CommandRecord, command_line, event_record
from kernel.shell.realtime import thread_at_ordinary_priority
from kernel.shell.record_file import RecordFile, fault_of


@dataclass
class RecorderStats:
    events: int = 0
    lines: int = 0
    gaps: int = 0
    flushes: int = 0
    error: str | None = None
    """The first write error (file, exception type and errno text)."""
    tail_written: bool | None = None
    """After a failure: whether what the run recorded from then on was written (into the
    reserve), all of it."""
    tail_error: str | None = None
    """After a failure, why the rest of the run was not written: it outgrew the reserve, or
    the disk refused it too (a read-only or failing file system: the reserve does not help)."""


class Recorder:
    """Buffers the run's record on the loop, writes it on a thread of its own.

    Raises (constructor):
        OSError: the journal's header line cannot be written.
    """

    def __init__(
        self, journal: RecordFile | None, decisions: RecordFile | None,
        head: Mapping[str, Any] | None = None, max_buffered: int = 200_000,
        flush_interval_s: float = 0.05,
    ) -> None:
        self._journal, self._decisions = journal, decisions
        self._events: list[str] = []
        self._lines: list[bytes] = []
        self._max = max_buffered
        self.flush_interval_s = flush_interval_s
        self.stats = RecorderStats()
        self.fault: RecorderFault | None = None
        """Set (once, by the writer thread) when a write failed; read by the control loop."""
        self._tail = _Tail()
        self._handed_over_at = time.monotonic()
        self._batches: queue.SimpleQueue[_Batch | None] = queue.SimpleQueue()
        self._queued = 0  # items handed over and not yet written (the bound covers them too)
        self._queued_lock = threading.Lock()
        if journal is not None and head is not None:
            line = (json.dumps(dict(head), allow_nan=True) + "\n").encode()
            journal.reserve_for(len(line))
            journal.append(line)
        self._writer = threading.Thread(target=self._write_batches, name="warden-recorder",
                                        daemon=True)
        self._writer.start()

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
        """Pass what is buffered to the writer thread; never waits for the disk."""
        self._handed_over_at = time.monotonic()
        if self._events or self._lines:
            with self._queued_lock:
                self._queued += len(self._events) + len(self._lines)
            self._batches.put(_Batch(self._events, self._lines, None))
            self._events, self._lines = [], []
            self.stats.flushes += 1

    def hand_over_if_due(self) -> None:
        """:meth:`hand_over` at most every ``flush_interval_s`` (a loop without the recorder
        task, e.g. a lockstep run, calls this once a tick)."""
        if time.monotonic() - self._handed_over_at >= self.flush_interval_s:
            self.hand_over()

    def flush(self) -> None:
        """Write everything buffered so far and wait until it is on its way to disk (end of a
        run, lockstep runs)."""
        self.hand_over()
        written = threading.Event()
        self._batches.put(_Batch([], [], written))
        while not written.wait(0.5):
            if not self._writer.is_alive():
                return

    def close(self) -> None:
        """Flush, then stop the writer thread (which writes a failed run's tail into the
        reserve), then close the files. Safe to call twice."""
        if not self._writer.is_alive():
            return
        self.flush()
        self._batches.put(None)
        self._writer.join()
        for record in (self._journal, self._decisions):
            if record is not None:
                try:
                    record.close()
                except OSError as error:
                    self._failed(record, error)

    async def run(self, started: Any = None) -> None:
        """Hand the buffers over periodically until cancelled (the last hand-over is
        :meth:`close`'s). A write failure does not end this task: it reaches the core (see
        :attr:`fault`), whose stop the run carries out before it ends.

        Nothing from the writer thread ever calls back into the event loop: the loop only
        puts batches on a queue, the thread only takes them off.
        """
        if started is not None:
            started()
        while True:
            await asyncio.sleep(self.flush_interval_s)
            self.hand_over()

    # -- the writer thread ----------------------------------------------------------------------

    def _write_batches(self) -> None:
        thread_at_ordinary_priority()
        while (batch := self._batches.get()) is not None:
            count = len(batch.events) + len(batch.lines)
            try:
                parts = self._parts(batch)
                if self.fault is None:
                    self._write(parts)
                else:
                    self._keep(parts)
            finally:
                with self._queued_lock:
                    self._queued -= count
                if batch.written is not None:
                    batch.written.set()
        if self.fault is not None:
            self._write_tail()

    def _parts(self, batch: _Batch) -> list[_Part]:
        parts = []
        if self._journal is not None and batch.events:
            data = ("\n".join(batch.events) + "\n").encode()
            parts.append(_Part(self._journal, data, len(batch.events)))
        if self._decisions is not None and batch.lines:
            parts.append(_Part(self._decisions, b"\n".join(batch.lines) + b"\n",
                               len(batch.lines)))
        return parts

    def _write(self, parts: list[_Part]) -> None:
        """Both files' space first, then their data: a batch that does not fit is written to
        neither, and is the first part of the tail."""
        for part in parts:
            try:
                part.file.reserve_for(len(part.data))
            except OSError as error:
                self._failed(part.file, error)
                self._keep(parts)
                return
        for index, part in enumerate(parts):
            try:
                part.file.append(part.data)
            except OSError as error:
                self._failed(part.file, error)
                self._keep(parts[index:])
                return

    def _keep(self, parts: list[_Part]) -> None:
        for part in parts:
            if not self._tail.add(part):
                self._count_gap(part.count)

    def _write_tail(self) -> None:
        """After a failure: the rest of the run into the reserve, if all of it fits, in the
        order it was recorded; the first part the disk refuses ends it (a part written after
        a lost one would leave a hole, and the decision log never gets ahead of the journal).
        Only a tail actually written is said to be written."""
        writing = self._tail.fits()
        if not writing:
            self.stats.tail_error = "it did not fit into the space the files keep reserved"
        for part in self._tail.parts:
            if writing:
                try:
                    part.file.append(part.data)
                    continue
                except OSError as error:
                    writing = False
                    self.stats.tail_error = f"{part.file.path.name}: {error.strerror or error}"
            self._count_gap(part.count)
        self.stats.tail_written = writing

    def files(self) -> dict[str, dict[str, Any]]:
        """What each file holds, as written (after :meth:`close`): its lines, the time of its
        last record (ms of run time; None for none, or a header only) and, if the data could not
        be written back to the disk at close, why."""
        held: dict[str, dict[str, Any]] = {}
        for record in (self._journal, self._decisions):
            if record is not None:
                held[record.path.name] = {"lines": record.lines,
                                          "ends_at_t_ms": _time_of(record.last_line),
                                          "sync_error": record.sync_error}
        return held

    def _failed(self, record: RecordFile, error: OSError) -> None:
        if self.fault is None:
            self.stats.error = f"{record.path.name}: {type(error).__name__}: {error}"
            self.fault = fault_of(error)

    def _count_gap(self, count: int) -> None:
        with self._queued_lock:  # stats are also counted on the loop thread
            self.stats.gaps += count


@dataclass(frozen=True, slots=True)
class _Batch:
    events: list[str]
    lines: list[bytes]
    written: threading.Event | None
    """Set once this batch (and everything queued before it) has been written."""


@dataclass(frozen=True, slots=True)
class _Part:
    file: RecordFile
    data: bytes
    count: int
    """Records (events or lines) in ``data``."""


@dataclass(slots=True)
class _Tail:
    """What a failed run records from its failing batch on, per file, in order."""

    parts: list[_Part] = field(default_factory=list)
    overflowed: bool = False
    _size: dict[int, int] = field(default_factory=dict)

    def add(self, part: _Part) -> bool:
        """Keep ``part``; False once a file's tail has outgrown its reserve (nothing more of it
        will be written: a tail with a hole would not be a record)."""
        size = self._size.get(id(part.file), 0) + len(part.data)
        if self.overflowed or size > part.file.reserved:
            self.overflowed = True
            return False
        self._size[id(part.file)] = size
        self.parts.append(part)
        return True

    def fits(self) -> bool:
        return not self.overflowed


def _time_of(line: bytes) -> float | None:
    """The run time of a record line (``t``), None for the header or no line."""
    try:
        record = json.loads(line) if line else None
    except ValueError:
        return None
    value = record.get("t") if isinstance(record, dict) else None
    return float(value) if isinstance(value, int | float) else None
