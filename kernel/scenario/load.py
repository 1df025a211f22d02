"""Reading a scenario (one JSON document) or a run journal (JSON lines) from disk.

A scenario has ``"format": "warden-scenario/1"`` and its control ticks are generated every
``control_period_ms`` from 0 to ``until``; it starts as if its session had just been accepted.
A journal's first line is the same header with ``"format": "warden-journal/1"``; every further
line is one event, its ticks are recorded events (a replay runs exactly the ticks the live run
ran), and it starts with no accepted session, as a live run does: the handshake is in it.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from assurance.clock import ms_to_ns
from kernel.core.config import CoreConfig
from kernel.core.events import TickEvent
from kernel.scenario.config import build_config
from kernel.scenario.events import Item, parse_events
from kernel.scenario.fields import ScenarioError, Where, number, text

SCENARIO_FORMAT = "warden-scenario/1"
JOURNAL_FORMAT = "warden-journal/1"


@dataclass(frozen=True, slots=True, eq=False)
class Scenario:
    name: str
    path: str
    config: CoreConfig
    events: list[Item]
    until_ns: int
    recorded_ticks: bool
    expect: list[dict[str, Any]] = field(default_factory=list)
    forbid: list[dict[str, Any]] = field(default_factory=list)

    def timeline(self) -> Iterator[Item]:
        """Events in order, with generated ticks after the events of the same instant."""
        if self.recorded_ticks:
            yield from self.events
            return
        period = self.config.control_period_ns
        tick = 0
        for event in self.events:
            while tick < event.t and tick <= self.until_ns:
                yield TickEvent(t=tick)
                tick += period
            yield event
        while tick <= self.until_ns:
            yield TickEvent(t=tick)
            tick += period


def load_scenario(path: str | Path) -> Scenario:
    path = Path(path)
    name = str(path)
    try:
        raw = path.read_text(encoding="utf-8")
    except OSError as error:
        raise ScenarioError(f"{name}: cannot read file: {error.strerror or error}") from None
    doc, lines = _parse(raw, name)
    return _scenario(doc, lines, name)


def _parse(raw: str, name: str) -> tuple[Any, list[Any] | None]:
    try:
        return json.loads(raw), None
    except json.JSONDecodeError as first_error:
        lines = [line for line in raw.splitlines() if line.strip()]
        if len(lines) < 2:
            raise ScenarioError(f"{name}: not valid JSON: {first_error}") from None
        parsed = []
        for number_, line in enumerate(lines, start=1):
            try:
                parsed.append(json.loads(line))
            except json.JSONDecodeError as error:
                raise ScenarioError(f"{name}: line {number_} is not valid JSON: {error}") from None
        return parsed[0], parsed[1:]


def _scenario(doc: Any, journal_events: list[Any] | None, name: str) -> Scenario:
    where = Where(name, "")
    if not isinstance(doc, dict):
        raise where.error("the top level must be a JSON object")
    fmt = doc.get("format", SCENARIO_FORMAT if journal_events is None else JOURNAL_FORMAT)
    if fmt not in (SCENARIO_FORMAT, JOURNAL_FORMAT):
        raise where.at("format").error(
            f"unknown format {fmt!r} (expected {SCENARIO_FORMAT!r} or {JOURNAL_FORMAT!r})")
    config = build_config(doc, where)
    if fmt == JOURNAL_FORMAT:  # a live run starts unconnected: its journal records the handshake
        config = dataclasses.replace(config, initial_session=None)
    raw_events = journal_events if journal_events is not None else doc.get("events")
    if raw_events is None:
        raise where.error("missing required key 'events'")
    events = parse_events(raw_events, where.at("events"), config.limits)
    last = events[-1].t if events else 0
    until = ms_to_ns(number(doc, "until", where, default=last / 1e6, minimum=0))
    return Scenario(
        name=text(doc, "name", where, default=Path(name).stem), path=name, config=config,
        events=events, until_ns=until, recorded_ticks=fmt == JOURNAL_FORMAT,
        expect=_matchers(doc, "expect", where), forbid=_matchers(doc, "forbid", where),
    )


def _matchers(doc: dict[str, Any], key: str, where: Where) -> list[dict[str, Any]]:
    raw = doc.get(key, [])
    if not isinstance(raw, list) or not all(isinstance(m, dict) for m in raw):
        raise where.at(key).error("must be a list of objects (line matchers)")
    return raw
