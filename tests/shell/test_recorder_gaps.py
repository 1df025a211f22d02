"""A recorder that falls behind by its whole buffer drops what does not fit, and counts every
dropped item as a gap (a journal with a gap is never taken for a replay of its run). One test
per kind of record (issue 15, item 14: a drop without a count survived the suite)."""

from __future__ import annotations

from pathlib import Path

from assurance.fallback import Owner
from kernel.core.effects import Setpoint
from kernel.core.events import StateEvent
from kernel.core.lines import QueueAction, QueueLine
from kernel.journal import CommandRecord
from kernel.shell.record_file import RecordFile
from kernel.shell.recorder import Recorder

RESERVE = 64 * 1024
BOUND = 3


def _recorder(tmp_path: Path) -> Recorder:
    return Recorder(RecordFile(tmp_path / "journal.jsonl", RESERVE),
                    RecordFile(tmp_path / "decisions.jsonl", RESERVE), max_buffered=BOUND)


def _journal_lines(tmp_path: Path) -> int:
    return len((tmp_path / "journal.jsonl").read_bytes().splitlines())


def test_events_beyond_the_buffer_are_counted_as_gaps(tmp_path: Path) -> None:
    recorder = _recorder(tmp_path)
    for t in range(BOUND + 2):
        recorder.event(StateEvent(t=t, q=(0.0,) * 6))
    recorder.close()
    assert (recorder.stats.events, recorder.stats.gaps) == (BOUND, 2)
    assert _journal_lines(tmp_path) == BOUND


def test_commands_beyond_the_buffer_are_counted_as_gaps(tmp_path: Path) -> None:
    recorder = _recorder(tmp_path)
    stop = Setpoint(q=(0.0,) * 6, gripper=None, owner=Owner.FALLBACK)
    for t in range(BOUND + 2):
        recorder.command(CommandRecord(t=t, effect=stop))
    recorder.close()
    assert (recorder.stats.events, recorder.stats.gaps) == (BOUND, 2)
    assert _journal_lines(tmp_path) == BOUND


def test_decision_lines_beyond_the_buffer_are_counted_as_gaps(tmp_path: Path) -> None:
    recorder = _recorder(tmp_path)
    recorder.lines([QueueLine(t=0, action=QueueAction.PURGE, queue_epoch=0)] * BOUND)
    recorder.lines([QueueLine(t=1, action=QueueAction.PURGE, queue_epoch=0)] * 2)
    recorder.close()
    assert (recorder.stats.lines, recorder.stats.gaps) == (BOUND, 2)
    assert len((tmp_path / "decisions.jsonl").read_bytes().splitlines()) == BOUND
