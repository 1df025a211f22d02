"""``warden replay``: the core on a virtual clock, driven by a scenario or a journal.

This is the same core that decides a live run; only the clock differs. The decision log is a
sequence of JSON lines whose bytes depend on nothing but the input file.

A scenario's long admission work (:mod:`kernel.core.jobs`) runs at once, at the instant the core
asks for it. A journal carries the results its run computed, and they are fed as recorded; it
also carries every command the run wrote to its driver, and the replay compares each with the
command the core decides now, bit for bit, keeping the first difference.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import msgspec

from kernel.core.effects import Compute, Motion
from kernel.core.events import ComputedEvent, Event
from kernel.core.jobs import run_job
from kernel.core.lines import Line, encode
from kernel.core.runtime import Core
from kernel.journal import CommandOrigin, CommandRecord
from kernel.scenario.load import Scenario


@dataclass(slots=True)
class Replay:
    """One replay: iterate :meth:`lines`; then read what the command comparison found."""

    scenario: Scenario
    core: Core = field(init=False)
    commands_checked: int = 0
    first_difference: str | None = None
    _decided: deque[tuple[int, Motion]] = field(default_factory=deque)

    def __post_init__(self) -> None:
        self.core = Core(self.scenario.config)

    def lines(self) -> Iterator[Line]:
        recorded_results = self.scenario.recorded_ticks
        for item in self.scenario.timeline():
            if isinstance(item, CommandRecord):
                self._compare(item)
                continue
            yield from self._step(item, recorded_results)
        # A run ends (or is killed) between a tick and writing its command: one decision
        # without a record at the very end is that, more is a difference.
        if len(self._decided) > 1 and self.first_difference is None and self.commands_checked:
            t, effect = self._decided[0]
            self.first_difference = (f"at {t / 1e6:g} ms the core decided {_text(effect)}, "
                                     "and the journal records no command for it")

    def _step(self, event: Event, recorded_results: bool) -> Iterator[Line]:
        step = self.core.step(event)
        yield from step.lines
        if recorded_results:  # a journal: its commands follow, to be compared
            motion = step.motion
            if motion is not None:
                self._decided.append((event.t, motion))
            return
        for effect in step.effects:
            if isinstance(effect, Compute):
                config = self.core.config
                result = run_job(effect.job, config.limits, config.cartesian,
                                 config.collision)
                yield from self._step(ComputedEvent(t=event.t, result=result), False)

    def _compare(self, record: CommandRecord) -> None:
        if record.origin is not CommandOrigin.CORE:
            return  # the shell's own stop after a failed tick: no decision to compare with
        self.commands_checked += 1
        if self.first_difference is not None:
            return
        if not self._decided:
            self.first_difference = (f"at {record.t / 1e6:g} ms the journal records "
                                     f"{_text(record.effect)}, the core decided nothing")
            return
        t, decided = self._decided.popleft()
        if not same_bits(decided, record.effect):
            self.first_difference = (f"at {t / 1e6:g} ms (command {self.commands_checked}) "
                                     f"the journal records {_text(record.effect)}, the core "
                                     f"decided {_text(decided)}")


_bits = msgspec.msgpack.Encoder()


def same_bits(decided: Motion, recorded: Motion) -> bool:
    """Equal to the bit: every float as its 64 bits (``==`` would take -0.0 for 0.0)."""
    return _bits.encode(decided) == _bits.encode(recorded)


def _text(effect: Motion) -> str:
    return msgspec.json.encode(effect).decode()


def replay(scenario: Scenario) -> Iterator[Line]:
    yield from Replay(scenario).lines()


def replay_bytes(scenario: Scenario) -> bytes:
    return b"".join(encode(line) + b"\n" for line in replay(scenario))


# -- expectations (the ``expect`` / ``forbid`` keys of a scenario) -------------------------------


def as_dict(line: Line) -> dict[str, Any]:
    return msgspec.json.decode(encode(line))


def matches(line: Mapping[str, Any], matcher: Mapping[str, Any]) -> bool:
    """True when every key of ``matcher`` holds in ``line``.

    Dotted keys reach into objects (``sent.chunk_id``); ``reasons`` compares as a set;
    ``reasons_include`` requires a subset; ``t_min``/``t_max`` bound the time.
    """
    for key, expected in matcher.items():
        if key == "t_min":
            if line.get("t", -1) < expected:
                return False
        elif key == "t_max":
            if line.get("t", float("inf")) > expected:
                return False
        elif key == "reasons_include":
            if not set(expected) <= set(line.get("reasons", ())):
                return False
        elif key == "reasons":
            if set(expected) != set(line.get("reasons", ())):
                return False
        elif _lookup(line, key) != expected:
            return False
    return True


_MISSING = object()


def _lookup(line: Mapping[str, Any], dotted: str) -> Any:
    value: Any = line
    for part in dotted.split("."):
        if not isinstance(value, Mapping) or part not in value:
            return _MISSING
        value = value[part]
    return value


def check_expectations(scenario: Scenario, lines: list[dict[str, Any]]) -> list[str]:
    """Every ``expect`` matcher must match a line; no ``forbid`` matcher may match one."""
    problems = []
    for matcher in scenario.expect:
        if not any(matches(line, matcher) for line in lines):
            problems.append(f"expected a line matching {matcher}")
    for matcher in scenario.forbid:
        hits = [line for line in lines if matches(line, matcher)]
        if hits:
            problems.append(f"forbidden line matching {matcher} at t={hits[0].get('t')}")
    return problems
