"""A run whose record cannot be written any more: the core stops the arm (RECORDER_FAILED),
the run ends with exit 3 and says why on stderr, and what the record holds still replays.

Real file systems only (tests/filesystems.py): a tmpfs that fills up under a simulated cell on
the virtual clock, and an ext4 image that the kernel turns read-only under a cell on the wall
clock (the live shell: recorder task, supervisor, policy server, job worker).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest

from kernel.app.live import run_live
from kernel.app.session import RunContext
from kernel.cli import main
from kernel.cli_run import report_record_failure
from kernel.core.lines import Line, encode
from kernel.settings import OperatorSettings
from kernel.shell.loop import run
from tests.cell.harness import manifest
from tests.filesystems import ext4_image, small_tmpfs

# Two reserves of 1 MiB (kernel/shell/record_file.py) and about 1 MB for the run itself: the
# disk fills in the first cycle of the simulated cell, whose record is some 3 MB.
DISK = "3m"


def _run_dir(root: Path) -> Path:
    (directory,) = [p for p in root.iterdir() if p.is_dir() and p.name != "lost+found"]
    return directory


def _lines(path: Path) -> list[dict[str, Any]]:
    data = path.read_bytes()
    assert data.endswith(b"\n"), f"{path.name} ends in a whole line"
    return [json.loads(line) for line in data.splitlines()]


def test_a_full_disk_stops_the_arm_and_ends_the_run_with_exit_3(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with small_tmpfs(tmp_path / "disk", DISK) as disk:
        code = main(["run", "--clock", "virtual", "--cycles", "1", "--journal-dir", str(disk)])
        err = capsys.readouterr().err
        assert code == 3, err
        assert "the run's record could not be written" in err and "No space left" in err
        assert "the core stopped the arm (RECORDER_FAILED)" in err
        directory = _run_dir(disk)
        events = _lines(directory / "journal.jsonl")
        decisions = _lines(directory / "decisions.jsonl")
        (failure,) = [e for e in events if e.get("kind") == "recorder"]
        assert failure["fault"] == "no_space"
        (stop,) = [d for d in decisions if d.get("trigger") == "RECORDER_FAILED"]
        assert (stop["to"], stop["t"]) == ("CONTROLLER_STOP", failure["t"])
        # The failure's tick is the run's last: the core's stop, written to the device.
        last_tick = [d for d in decisions if d["kind"] == "tick"][-1]
        assert (last_tick["t"], last_tick["command"], last_tick["owner"]) == (
            failure["t"], "stop", "safety")
        assert events[-1]["kind"] == "command" and events[-1]["effect"]["effect"] == "stop"
        assert json.loads((directory / "summary.json").read_text())["journal"]["gaps"] == 0
        assert main(["replay", str(directory / "journal.jsonl")]) == 0  # identical, complete
        assert "identical: " in capsys.readouterr().err


class _FailTheDisk:
    """After ``after`` ticks, has the kernel turn the journal's file system read-only; keeps
    every decision line the core makes from then on (they reach no disk)."""

    def __init__(self, fail: Any, after: int) -> None:
        self.fail, self.after = fail, after
        self.ticks = 0
        self.lines: list[Line] = []
        self.context: RunContext | None = None

    def __call__(self, context: RunContext) -> bool:
        self.ticks += 1
        if self.ticks == self.after:
            self.context = context
            context.cell.gateway.listeners.append(self.lines.extend)
            self.fail()
        return False


@pytest.mark.slow
@pytest.mark.parametrize(("how", "fault", "text"), [
    ("read-only", "read_only", "Read-only file system"),
    ("eio", "io_error", "Input/output error"),
])
def test_a_disk_failing_mid_run_stops_the_arm_and_the_report_matches_the_files(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], how: str, fault: str,
        text: str) -> None:
    with ext4_image(tmp_path) as fs:
        hook = _FailTheDisk(fs.fail if how == "read-only" else fs.fail_with_eio, after=500)
        # An operator socket of its own: the default one may be another warden's on this host.
        cell = dataclasses.replace(manifest("sim-ur5e.toml", cycles=1), operator=OperatorSettings(
            socket=str(tmp_path / "operator.sock")))
        summary = run(run_live(cell, fs.mount_point, hook=hook))
        assert hook.context is not None, "the run ended before the disk failed"
        journal = summary["journal"]
        assert journal["fault"] == fault and journal["core_told"]
        assert text in journal["error"]
        assert not summary["timed_out"]
        (cut,) = summary["cycles"]["detail"]  # the cycle under way: attempted, not verified
        assert (cut["verified"], cut["reason"]) == (False, "the run's record could not be written")
        lines = [json.loads(encode(line)) for line in hook.lines]
        (stop,) = [line for line in lines if line.get("trigger") == "RECORDER_FAILED"]
        assert stop["to"] == "CONTROLLER_STOP"
        ticks = [line for line in lines if line["kind"] == "tick" and line["t"] >= stop["t"]]
        assert ticks and all(t["command"] == "stop" for t in ticks)
        assert hook.context.cell.core.status().mode == "CONTROLLER_STOP"
        # The reserve is no help on a disk that refuses every write: the tail is lost, and
        # the report says so rather than what the recorder meant to write.
        assert journal["tail_written"] is False and text in journal["tail_error"]
        assert report_record_failure(summary)
        err = capsys.readouterr().err
        assert "was NOT written" in err and text in err and "written into the space" not in err
        # What the summary and stderr say each file holds is what the disk holds.
        directory = _run_dir(fs.mounted_again() if how == "eio" else fs.mount_point)
        for name, held in journal["files"].items():
            on_disk = (directory / name).read_bytes().splitlines()
            last_t = json.loads(on_disk[-1])["t"]
            assert (held["lines"], held["ends_at_t_ms"]) == (len(on_disk), last_t), name
            assert f"{name}: {len(on_disk)} lines written, the last at t={last_t:.3f} ms" in err
        assert journal["files"]["decisions.jsonl"]["ends_at_t_ms"] < stop["t"]
        # Neither file holds anything the other does not: what they hold replays as it was.
        assert main(["replay", str(directory / "journal.jsonl")]) == 0
