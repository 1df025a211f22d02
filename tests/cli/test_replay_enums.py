"""Phase requests, controller reasons and command origins are enums (issue 16, item 6).

A scenario or journal decodes them into :class:`~skills.phases.TaskPhase`,
:class:`~skills.task_fsm.Requester`, :class:`~assurance.reasons.ReasonCode` and
:class:`~kernel.journal.CommandOrigin` members (the core compares members, never text); an
unknown value is a file error: exit 2, naming the file, the key and the values it may take.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from assurance.reasons import ReasonCode
from kernel.cli import main
from kernel.core.events import ControllerEvent, PhaseEvent
from kernel.journal import JOURNAL_FORMAT, CommandOrigin, CommandRecord
from kernel.scenario.load import load_scenario
from skills.phases import TaskPhase
from skills.task_fsm import Requester

ROOT = Path(__file__).resolve().parents[2]
SEED = ROOT / "manifests" / "scenarios" / "seed_stale_chunk.json"
STOP = {"effect": "stop", "gripper": None, "owner": "fallback"}
"""A command record's motion effect, as a journal carries it."""


def _scenario(tmp_path: Path, *extra: dict[str, Any]) -> Path:
    doc = json.loads(SEED.read_text())
    doc["events"] += list(extra)
    doc.pop("expect"), doc.pop("forbid")
    path = tmp_path / "scenario.json"
    path.write_text(json.dumps(doc))
    return path


def _journal(tmp_path: Path, *extra: dict[str, Any]) -> Path:
    """The seed scenario as a run journal: its header, then one line per event."""
    doc = json.loads(SEED.read_text())
    head = {k: v for k, v in doc.items() if k not in ("events", "until", "expect", "forbid",
                                                      "description")}
    lines = [{**head, "format": JOURNAL_FORMAT}, *doc["events"], *extra]
    path = tmp_path / "journal.jsonl"
    path.write_text("".join(json.dumps(line) + "\n" for line in lines))
    return path


LATE = 10_000
"""An event time after every event of the seed scenario (ms)."""


def test_the_fields_decode_into_enum_members(tmp_path: Path) -> None:
    path = _journal(tmp_path, {"t": LATE, "kind": "phase", "to": "RETREAT", "by": "policy"},
                    {"t": LATE, "kind": "controller", "status": "fault",
                     "reason": "WATCHDOG"},
                    {"t": LATE, "kind": "command", "effect": STOP, "origin": "shell"},
                    {"t": LATE, "kind": "command", "effect": STOP})
    *_, phase, controller, shell, core = load_scenario(path).events
    assert isinstance(phase, PhaseEvent) and isinstance(controller, ControllerEvent)
    assert (type(phase.to), phase.to, type(phase.by), phase.by) == (
        TaskPhase, TaskPhase.RETREAT, Requester, Requester.POLICY)
    assert type(controller.reason) is ReasonCode and controller.reason is ReasonCode.WATCHDOG
    assert isinstance(shell, CommandRecord) and isinstance(core, CommandRecord)
    assert type(shell.origin) is CommandOrigin and shell.origin is CommandOrigin.SHELL
    assert core.origin is CommandOrigin.CORE


UNKNOWN = [
    ("phase", {"kind": "phase", "to": "FLYING"}, "to: unknown value 'FLYING'", "VERIFY"),
    ("requester", {"kind": "phase", "to": "RETREAT", "by": "cron"},
     "by: unknown value 'cron'", "fsm, policy, operator"),
    ("controller reason", {"kind": "controller", "status": "fault", "reason": "GREMLIN"},
     "reason: unknown value 'GREMLIN'", "WATCHDOG"),
]


@pytest.mark.parametrize(("case", "event", "message", "listed"), UNKNOWN,
                         ids=[case[0] for case in UNKNOWN])
@pytest.mark.parametrize("form", ["scenario", "journal"])
def test_an_unknown_value_is_refused_with_exit_2(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str], form: str,
                                                 case: str, event: dict[str, Any],
                                                 message: str, listed: str) -> None:
    write = _scenario if form == "scenario" else _journal
    path = write(tmp_path, {"t": LATE, **event})
    assert main(["replay", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and message in err and listed in err, err
    assert "Traceback" not in err


def test_an_unknown_command_origin_is_refused_with_exit_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _journal(tmp_path, {"t": LATE, "kind": "command", "effect": STOP,
                               "origin": "robot"})
    assert main(["replay", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "origin: unknown value 'robot'" in err, err
    assert "expected one of core, shell" in err and "Traceback" not in err
