"""``warden replay``: the core on a virtual clock, driven by a scenario or a journal.

This is the same core that decides a live run; only the clock differs. The decision log is a
sequence of JSON lines whose bytes depend on nothing but the input file.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

import msgspec

from kernel.core.lines import Line, encode
from kernel.core.runtime import Core
from kernel.scenario import Scenario


def replay(scenario: Scenario) -> Iterator[Line]:
    core = Core(scenario.config)
    for event in scenario.timeline():
        yield from core.handle(event)


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
