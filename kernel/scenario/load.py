"""Reading a scenario (one JSON document) or a run journal (JSON lines) from disk.

A scenario has ``"format": "warden-scenario/1"`` and its control ticks are generated every
``control_period_ms`` from 0 to ``until``; it starts as if its session had just been accepted.
A journal's first line is the same header with ``"format": "warden-journal/1"``; every further
line is one event, its ticks are recorded events (a replay runs exactly the ticks the live run
ran), and it starts with no accepted session, as a live run does: the handshake is in it.

A journal is written in whole lines, so the only damage a killed run can leave is an
incomplete last line (no newline, not JSON). Such a line is dropped: the journal replays up to
its last complete line, and :attr:`Scenario.cut` says which line was dropped. Any other broken
line is an invalid file.
"""

from __future__ import annotations

import codecs
import dataclasses
import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from assurance.clock import ms_to_ns
from kernel.config.build import build_config
from kernel.core.config import CoreConfig
from kernel.core.events import TickEvent
from kernel.scenario.bounds import TICKS_MAX, UNTIL_MAX_MS
from kernel.scenario.document import check_document, decoded, parse_json, read_bytes
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
    cut: int | None = None
    """A journal whose last line was incomplete: the number of that line, dropped (the replay
    covers the lines before it)."""

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
    """Read and check a scenario or a journal.

    Raises:
        ScenarioError: naming the file, the place and the problem, for anything that is not a
            valid scenario (unreadable, not UTF-8, not JSON, a value out of its bounds, ...).
    """
    name = str(path)
    data = read_bytes(Path(path), name)
    try:
        raw = decoded(data, name)
    except ScenarioError:
        raw = _before_cut_character(data, name)
    doc, lines, cut = _parse(raw, name)
    return dataclasses.replace(_scenario(doc, lines, name), cut=cut)


def _before_cut_character(data: bytes, name: str) -> str:
    """A journal cut inside a character of its last line (a multi-byte sequence left
    incomplete at the very end): the text without that partial character (the line then reads
    as incomplete). Any other byte that is not UTF-8 stays an error.

    Raises:
        ScenarioError: the file is not UTF-8 for another reason.
    """
    try:
        return codecs.getincrementaldecoder("utf-8")().decode(data, final=False)
    except UnicodeDecodeError:
        return decoded(data, name)  # raises, naming the place


def _parse(raw: str, name: str) -> tuple[Any, list[Any] | None, int | None]:
    try:
        doc = parse_json(raw, name)
    except json.JSONDecodeError as first_error:
        lines = [(number_, line) for number_, line in enumerate(raw.splitlines(), start=1)
                 if line.strip()]
        if len(lines) < 2:
            raise ScenarioError(f"{name}: not valid JSON: {first_error}") from None
        parsed, cut = _json_lines(lines, raw.endswith("\n"), name)
        check_document(parsed[0], Where(name, ""))
        check_document(parsed[1:], Where(name, "events"))
        return parsed[0], parsed[1:], cut
    check_document(doc, Where(name, ""))
    return doc, None, None


def _json_lines(lines: list[tuple[int, str]], terminated: bool,
                name: str) -> tuple[list[Any], int | None]:
    """Every line parsed; an unterminated last line that is not JSON is dropped as cut.

    Raises:
        ScenarioError: a line that is not JSON, other than a cut last line.
    """
    parsed = []
    for index, (number_, line) in enumerate(lines):
        try:
            parsed.append(parse_json(line, name, number_))
        except json.JSONDecodeError as error:
            if index == len(lines) - 1 and not terminated and index >= 1:
                return parsed, number_
            raise ScenarioError(f"{name}: line {number_} is not valid JSON: {error}") from None
    return parsed, None


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
    if fmt == SCENARIO_FORMAT:
        _check_until(until, config.control_period_ns, "until" in doc, where.at("until"))
    return Scenario(
        name=text(doc, "name", where, default=Path(name).stem), path=name, config=config,
        events=events, until_ns=until, recorded_ticks=fmt == JOURNAL_FORMAT,
        expect=_matchers(doc, "expect", where), forbid=_matchers(doc, "forbid", where),
    )


def _check_until(until_ns: int, period_ns: int, given: bool, where: Where) -> None:
    """A scenario's ticks are generated up to ``until``: bound how many (a journal's ticks are
    recorded lines, bounded by the file itself)."""
    until_ms = until_ns / 1e6
    if until_ms > UNTIL_MAX_MS:
        what = f"{until_ms:g} ms" if given else (
            f"not set, and its default, the time of the last event ({until_ms:g} ms),")
        raise where.error(f"{what} is longer than a scenario may run: at most "
                          f"{UNTIL_MAX_MS:g} ms (one hour)")
    ticks = until_ns // period_ns + 1
    if ticks > TICKS_MAX:
        raise where.error(f"generates {ticks} ticks at timing.control_period_ms "
                          f"{period_ns / 1e6:g}; at most {TICKS_MAX} (lengthen the period or "
                          "shorten the scenario)")


def _matchers(doc: dict[str, Any], key: str, where: Where) -> list[dict[str, Any]]:
    raw = doc.get(key, [])
    if not isinstance(raw, list) or not all(isinstance(m, dict) for m in raw):
        raise where.at(key).error("must be a list of objects (line matchers)")
    return raw
