"""The recorder writes on its own thread: a stalled disk never stalls the event loop."""

from __future__ import annotations

import asyncio
import io
import json
import threading

import pytest

from kernel.core.events import StateEvent
from kernel.shell.recorder import Recorder, RecorderError


class _StalledDisk(io.StringIO):
    """A journal whose writes block until the test releases them, like a hung disk."""

    def __init__(self) -> None:
        super().__init__()
        self.writing = threading.Event()
        self.release = threading.Event()
        self.gave_up = False

    def write(self, text: str) -> int:
        self.writing.set()
        # Released by the test from the event loop: only possible if the loop is not the
        # thread stuck in here. (A loop-thread write would sit out the whole timeout.)
        self.gave_up = self.gave_up or not self.release.wait(timeout=5)
        return super().write(text)


async def test_a_stalled_write_leaves_the_loop_running() -> None:
    disk = _StalledDisk()
    recorder = Recorder(disk, None, flush_interval_s=0.001)
    recorder.event(StateEvent(t=1_000_000, q=(0.0,) * 6))
    task = asyncio.create_task(recorder.run())
    while not disk.writing.is_set():
        await asyncio.sleep(0.001)
    # The writer thread is blocked inside write(); the loop still runs other work.
    turns = 0
    for _ in range(20):
        await asyncio.sleep(0)
        turns += 1
    assert turns == 20 and not task.done()
    recorder.event(StateEvent(t=2_000_000, q=(0.1,) * 6))
    disk.release.set()
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    recorder.close()
    assert not disk.gave_up
    records = [json.loads(line) for line in disk.getvalue().splitlines()]
    assert [r["t"] for r in records] == [1, 2]  # both events, in order, none lost at shutdown


class _FullDisk(io.StringIO):
    """A journal on a disk that fills up after ``room`` writes."""

    def __init__(self, room: int) -> None:
        super().__init__()
        self.room = room

    def write(self, text: str) -> int:
        if self.room <= 0:
            raise OSError(28, "No space left on device")
        self.room -= 1
        return super().write(text)


def _state(t_ms: int) -> StateEvent:
    return StateEvent(t=t_ms * 1_000_000, q=(0.0,) * 6)


async def test_a_failing_disk_ends_the_run_and_counts_what_was_lost() -> None:
    disk = _FullDisk(room=1)  # the head line fits, nothing after it
    recorder = Recorder(disk, None, head={"format": "warden-journal/1"},
                        flush_interval_s=0.001)
    recorder.event(_state(1))
    recorder.event(_state(2))
    with pytest.raises(RecorderError, match="No space left"):
        await asyncio.wait_for(recorder.run(), timeout=10)
    recorder.event(_state(3))
    recorder.close()  # returns: the writer never dies, nothing waits on it forever
    assert recorder.stats.gaps == 3 and "OSError" in (recorder.stats.error or "")
    assert disk.getvalue().count("\n") == 1  # only the head


def test_close_without_a_running_loop_flushes_everything() -> None:
    disk = io.StringIO()
    recorder = Recorder(disk, None)
    for t in range(5):
        recorder.event(_state(t))
    recorder.close()
    recorder.close()  # idempotent
    assert [json.loads(line)["t"] for line in disk.getvalue().splitlines()] == [0, 1, 2, 3, 4]
    assert recorder.stats.gaps == 0 and recorder.stats.error is None
