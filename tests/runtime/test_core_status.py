"""The core's state is private; the shell reads a typed, read-only status (issue 16, item 4).

Six sites in ``kernel/app`` and ``kernel/shell`` (and the gateway, a stand-in policy and two
benchmarks) read ``Core.state`` directly: the shell was coupled to the core's internals and
could change a decision without an event (no journal records it, no replay repeats it). They
now read :meth:`Core.status`; tests that check the core's inner workings use the clearly named
:meth:`Core.inspect_state`, which nothing outside the core and the tests may call.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

from assurance.fallback import Mode
from assurance.reasons import ReasonCode
from kernel.core.events import ControllerEvent, ControllerStatus
from kernel.core.runtime import Core
from skills.phases import TaskPhase
from tests.runtime.machine_setup import core_config, feed

ROOT = Path(__file__).resolve().parents[2]
OUTSIDE_THE_CORE = ("kernel", "stubs", "drivers", "bench", "tools")
"""Where no code may reach into the core's state (``kernel/core`` itself excepted)."""


def test_the_status_names_the_fallback_and_its_cause() -> None:
    core = Core(core_config("FREE_SPACE"))
    before = core.status()
    assert (before.mode, before.cause, before.phase) == (Mode.RUNNING, None,
                                                         TaskPhase.FREE_SPACE)
    feed(core, ControllerEvent(t=1_000_000, status=ControllerStatus.REJECT))
    after = core.status()
    assert (after.mode, after.cause) == (Mode.CONTROLLER_STOP, ReasonCode.CONTROLLER_REJECT)
    assert before.mode is Mode.RUNNING  # a status is a copy: it does not follow the core


def test_the_status_is_read_only_and_the_state_is_not_public() -> None:
    core = Core(core_config("FREE_SPACE"))
    with pytest.raises(AttributeError):
        core.status().mode = Mode.SAFE_HOLD  # type: ignore[misc]
    assert not hasattr(core, "state")


def reaches_into_the_core(path: str, source: str) -> Iterator[str]:
    """``path:line`` of every read of a core's state: ``<...>core.state``, ``<...>core._state``
    or ``inspect_state`` (the tests' accessor)."""
    for node in ast.walk(ast.parse(source, filename=path)):
        if not isinstance(node, ast.Attribute):
            continue
        owner = node.value
        named = owner.attr if isinstance(owner, ast.Attribute) else getattr(owner, "id", "")
        if node.attr == "inspect_state" or (node.attr in ("state", "_state")
                                            and named.endswith("core")):
            yield f"{path}:{node.lineno}: {ast.unparse(node)}"


def test_nothing_outside_the_core_reads_its_state() -> None:
    found = []
    for folder in OUTSIDE_THE_CORE:
        for file in sorted((ROOT / folder).rglob("*.py")):
            path = file.relative_to(ROOT).as_posix()
            if not path.startswith("kernel/core/"):
                found += reaches_into_the_core(path, file.read_text(encoding="utf-8"))
    assert not found, "read the core's status instead:\n" + "\n".join(found)


def test_the_checker_finds_every_way_in() -> None:
    source = ("a = cell.core.state.epoch\nb = core._state\nc = gateway.core.inspect_state()\n"
              "d = driver.state\ne = self.state\n")
    assert sorted(hit.split(": ")[0] for hit in reaches_into_the_core("x.py", source)) == [
        "x.py:1", "x.py:2", "x.py:3"]
