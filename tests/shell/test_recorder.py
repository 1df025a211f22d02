"""The recorder writes on its own thread: a stalled disk never stalls the event loop; a full,
failing or read-only disk is reported once (``Recorder.fault``), both files end in whole lines,
and what follows the failure goes into the space each file keeps reserved.

The disks are real (a small tmpfs, an ext4 image turned read-only by the kernel) except for
the one write error no file system here produces on demand, EIO part-way through a write,
which is injected at the record file's write boundary.
"""

from __future__ import annotations

import asyncio
import errno
import json
import threading
from pathlib import Path

from kernel.core.events import RecorderFault, StateEvent
from kernel.core.lines import QueueAction, QueueLine
from kernel.shell.record_file import RecordFile, journal_directory_problem
from kernel.shell.recorder import Recorder
from tests.filesystems import ext4_image, read_only_tmpfs, small_tmpfs

RESERVE = 64 * 1024


def _state(t_ms: int) -> StateEvent:
    return StateEvent(t=t_ms * 1_000_000, q=(0.0,) * 6)


def _line(t_ms: int) -> QueueLine:
    return QueueLine(t=t_ms, action=QueueAction.PURGE, queue_epoch=0)


def _records(path: Path) -> list[dict]:
    data = path.read_bytes()
    assert data.endswith(b"\n"), "a record file ends with a whole line"
    return [json.loads(line) for line in data.splitlines()]


class _StalledFile(RecordFile):
    """A journal whose writes block until the test releases them, like a hung disk."""

    def __init__(self, path: Path) -> None:
        super().__init__(path, RESERVE)
        self.writing = threading.Event()
        self.release = threading.Event()
        self.gave_up = False

    def _write(self, data: memoryview) -> int:
        self.writing.set()
        # Released by the test from the event loop: only possible if the loop is not the
        # thread stuck in here. (A loop-thread write would sit out the whole timeout.)
        self.gave_up = self.gave_up or not self.release.wait(timeout=5)
        return super()._write(data)


async def test_a_stalled_write_leaves_the_loop_running(tmp_path: Path) -> None:
    disk = _StalledFile(tmp_path / "journal.jsonl")
    recorder = Recorder(disk, None, flush_interval_s=0.001)
    recorder.event(_state(1))
    task = asyncio.create_task(recorder.run())
    while not disk.writing.is_set():
        await asyncio.sleep(0.001)
    # The writer thread is blocked inside write(); the loop still runs other work.
    turns = 0
    for _ in range(20):
        await asyncio.sleep(0)
        turns += 1
    assert turns == 20 and not task.done()
    recorder.event(_state(2))
    disk.release.set()
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    recorder.close()
    assert not disk.gave_up
    # both events, in order, none lost at shutdown
    assert [r["t"] for r in _records(tmp_path / "journal.jsonl")] == [1, 2]


def _fill_until_fault(recorder: Recorder, limit: int = 100_000) -> int:
    """Record events and lines, handing them over as a run does, until a write fails."""
    for t in range(1, limit):
        recorder.event(_state(t))
        recorder.lines([_line(t)])
        if t % 50 == 0:
            recorder.flush()
            if recorder.fault is not None:
                return t
    raise AssertionError(f"the disk never filled in {limit} events")


def test_a_full_disk_is_reported_and_the_rest_goes_into_the_reserve(tmp_path: Path) -> None:
    with small_tmpfs(tmp_path / "disk", "512k") as disk:
        journal = RecordFile(disk / "journal.jsonl", RESERVE)
        decisions = RecordFile(disk / "decisions.jsonl", RESERVE)
        recorder = Recorder(journal, decisions, head={"format": "warden-journal/1"})
        failed_at = _fill_until_fault(recorder)
        assert recorder.fault is RecorderFault.NO_SPACE
        assert "No space left" in (recorder.stats.error or "")
        recorder.event(_state(failed_at + 1))  # what the run records after the failure
        recorder.lines([_line(failed_at + 1)])
        recorder.close()
        assert recorder.stats.tail_written is True and recorder.stats.gaps == 0
        events = [r["t"] for r in _records(disk / "journal.jsonl")[1:]]
        lines = [r["t"] for r in _records(disk / "decisions.jsonl")]
        assert events == lines == list(range(1, failed_at + 2))  # whole, in order, no hole


def test_a_tail_larger_than_the_reserve_is_not_written_at_all(tmp_path: Path) -> None:
    with small_tmpfs(tmp_path / "disk", "512k") as disk:
        journal = RecordFile(disk / "journal.jsonl", RESERVE)
        decisions = RecordFile(disk / "decisions.jsonl", RESERVE)
        recorder = Recorder(journal, decisions)
        failed_at = _fill_until_fault(recorder)
        before = len(_records(disk / "journal.jsonl"))
        for t in range(failed_at + 1, failed_at + 2000):  # far more than 64 kB
            recorder.event(_state(t))
            recorder.lines([_line(t)])
        recorder.close()
        assert recorder.stats.tail_written is False and recorder.stats.gaps > 0
        events = [r["t"] for r in _records(disk / "journal.jsonl")]
        lines = [r["t"] for r in _records(disk / "decisions.jsonl")]
        # Both files stop where the first failing batch would have started: the same prefix.
        assert len(events) == before and events == lines == list(range(1, before + 1))


def test_a_file_system_turned_read_only_is_reported(tmp_path: Path) -> None:
    with ext4_image(tmp_path) as fs:
        journal = RecordFile(fs.mount_point / "journal.jsonl", RESERVE)
        recorder = Recorder(journal, None, head={"format": "warden-journal/1"})
        for t in range(1, 100):
            recorder.event(_state(t))
        recorder.flush()
        fs.fail()
        recorder.event(_state(100))
        recorder.flush()
        assert recorder.fault is RecorderFault.READ_ONLY
        assert "Read-only file system" in (recorder.stats.error or "")
        recorder.close()
        # Tried, and the disk refused it: said so, counted, never hidden.
        assert recorder.stats.tail_written is False
        assert "Read-only file system" in (recorder.stats.tail_error or "")
        assert recorder.stats.gaps == 1
        # The header and 99 events, as written; the disk also refused to sync them at close.
        assert recorder.files()["journal.jsonl"] == {
            "lines": 100, "ends_at_t_ms": 99.0, "sync_error": "Read-only file system"}
        assert [r.get("t") for r in _records(journal.path)[1:]] == list(range(1, 100))


class _FailingMidWrite(RecordFile):
    """A disk that takes half of one write, then fails it with EIO."""

    def __init__(self, path: Path, fail_on: int) -> None:
        super().__init__(path, RESERVE)
        self.writes = 0
        self.fail_on = fail_on

    def _write(self, data: memoryview) -> int:
        self.writes += 1
        if self.writes == self.fail_on:
            super()._write(data[: len(data) // 2])
            raise OSError(errno.EIO, "Input/output error")
        return super()._write(data)


def test_an_error_mid_write_leaves_whole_lines_and_nothing_glued_to_them(
        tmp_path: Path) -> None:
    journal = _FailingMidWrite(tmp_path / "journal.jsonl", fail_on=3)
    recorder = Recorder(journal, None, head={"format": "warden-journal/1"})
    for t in range(1, 40):
        recorder.event(_state(t))
        if t % 10 == 0:
            recorder.flush()
    recorder.close()
    assert recorder.fault is RecorderFault.IO_ERROR
    # The half-written batch was cut back; the tail (retried into the reserve) follows it.
    assert [r.get("t") for r in _records(journal.path)[1:]] == list(range(1, 40))


def test_close_without_a_running_loop_flushes_everything(tmp_path: Path) -> None:
    journal = RecordFile(tmp_path / "journal.jsonl", RESERVE)
    recorder = Recorder(journal, None)
    for t in range(5):
        recorder.event(_state(t))
    recorder.close()
    recorder.close()  # idempotent
    assert [r["t"] for r in _records(journal.path)] == [0, 1, 2, 3, 4]
    assert recorder.stats.gaps == 0 and recorder.stats.error is None
    assert journal.path.stat().st_blocks * 512 < RESERVE  # the reserve was given back


def test_journal_directories_that_cannot_hold_a_journal_are_named(tmp_path: Path) -> None:
    assert journal_directory_problem(Path("/dev/null")) == "not a directory"
    assert "cannot write a file there" in (journal_directory_problem(Path("/proc")) or "")
    with read_only_tmpfs(tmp_path / "ro") as read_only:
        assert "Read-only file system" in (journal_directory_problem(read_only) or "")
    with small_tmpfs(tmp_path / "tiny", "1m") as tiny:  # less than the reserves need
        assert "No space left" in (journal_directory_problem(tiny) or "")
    assert journal_directory_problem(tmp_path / "new" / "runs") is None
    assert not any((tmp_path / "new" / "runs").iterdir())  # the probe is gone
