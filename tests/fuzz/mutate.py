"""Mutations of parsed documents (scenarios, journals, manifests) and of their bytes.

Hypothesis draws every choice, so a failing input shrinks to the one mutation that breaks a
loader. A document is mutated a few times (a value replaced by an extreme or mistyped one, a key
dropped or added, a value wrapped in deep nesting), then serialised as JSON or TOML, then
sometimes mutated as bytes (a flipped byte, an invalid UTF-8 sequence, a cut). Literals no
serialiser writes (an integer of 5000 digits, nesting 100 000 deep) are placed as markers and
spliced into the text.
"""

from __future__ import annotations

import copy
import json
import math
from typing import Any

from hypothesis import strategies as st

HUGE_INTEGER = "\x00huge-integer\x00"
"""Marker for a 5000-digit integer literal (no serialiser writes one: Python refuses to turn
such an int into text)."""
DEEP_NESTING = "\x00deep-nesting\x00"
"""Marker for arrays nested 100 000 deep (deeper than any parser's stack)."""
MARKERS = {HUGE_INTEGER: "9" * 5000, DEEP_NESTING: "[" * 100_000 + "]" * 100_000}

EXTREME_NUMBERS: list[Any] = [
    0, -1, 1, 2, -0.0, 0.5, 1e-9, -1e-9, 1e3, 1e6, 3.6e6, 3e8, 1e9, 1e12, 1e13, 4e12, 1e15,
    1e300, -1e300, math.inf, -math.inf, math.nan, 2**31, 2**53 + 1, 2**63 - 1, 2**63, -(2**63) - 1,
    2**64, 10**30, 10**400, 65535, 65536, 70000, 64, 65, 8 * math.pi, 100.0, 100.0001,
]
STRINGS: list[Any] = [
    "", " ", "x", "é", "\u202e", "\ud800", "\x00", "../../x", ".hidden", "-rf", "a/b",
    "sim", "ur_rtde", "virtual", "wall", "IDLE", "CONTACT", "NAP", "joint", "base_delta", "m",
    "ur5e", "kuka", "x" * 300, "1e3", "NaN",
]
KEYS = ["foo", "dof", "position_limits", "velocity_limits", "acceleration_limits", "state",
        "phase", "until", "events", "t", "kind", "q", "wire", "offset_ns", "cycles", "port",
        "name", "max_divergence", "trim", "Dof", "cyclez", ""]


def scalars() -> st.SearchStrategy[Any]:
    return st.one_of(
        st.sampled_from(EXTREME_NUMBERS), st.sampled_from(STRINGS),
        st.sampled_from([None, True, False, HUGE_INTEGER]),
        st.integers(), st.floats(allow_nan=True, allow_infinity=True),
        st.text(max_size=12),
    )


def values() -> st.SearchStrategy[Any]:
    leaves = scalars()
    return st.recursive(
        leaves,
        lambda inner: st.lists(inner, max_size=4) | st.dictionaries(
            st.sampled_from(KEYS) | st.text(max_size=6), inner, max_size=4),
        max_leaves=8,
    ) | st.sampled_from([DEEP_NESTING, _nested(40), _nested_object(40), [[0.0] * 6] * 6])


def _nested(depth: int) -> Any:
    value: Any = 0
    for _ in range(depth):
        value = [value]
    return value


def _nested_object(depth: int) -> Any:
    value: Any = 0
    for _ in range(depth):
        value = {"a": value}
    return value


def paths(doc: Any, limit: int = 4000) -> list[tuple[Any, ...]]:
    """Every place in ``doc`` (up to ``limit``), the root included, breadth first."""
    found: list[tuple[Any, ...]] = [()]
    queue: list[tuple[tuple[Any, ...], Any]] = [((), doc)]
    while queue and len(found) < limit:
        path, value = queue.pop(0)
        children = value.items() if isinstance(value, dict) else (
            enumerate(value) if isinstance(value, list) else ())
        for key, child in children:
            found.append((*path, key))
            queue.append(((*path, key), child))
    return found


def _parent(doc: Any, path: tuple[Any, ...]) -> Any:
    for key in path[:-1]:
        doc = doc[key]
    return doc


@st.composite
def mutated(draw: st.DrawFn, doc: Any, max_mutations: int = 3) -> Any:
    """``doc`` with one to ``max_mutations`` mutations (a deep copy; ``doc`` is untouched)."""
    doc = copy.deepcopy(doc)
    for _ in range(draw(st.integers(1, max_mutations))):
        places = [p for p in paths(doc) if p]
        if not places:
            return draw(values())
        path = draw(st.sampled_from(places))
        parent = _parent(doc, path)
        key = path[-1]
        operation = draw(st.sampled_from(OPERATIONS))
        if operation == "tweak":
            parent[key] = draw(_same_type(parent[key]))
        elif operation == "replace":
            parent[key] = draw(values())
        elif operation == "drop":
            del parent[key]
        elif operation == "add" and isinstance(parent, dict):
            parent[draw(st.sampled_from(KEYS) | st.text(max_size=8))] = draw(values())
        elif operation == "add":
            parent.insert(key, draw(values()))
        elif operation == "retype":
            parent[key] = _retyped(parent[key])
        elif operation == "scale" and isinstance(parent[key], int | float):
            parent[key] = _scaled(parent[key], draw(st.sampled_from([-1, 1e3, 1e9, 1e300,
                                                                     10**30])))
        else:
            parent[key] = _nested_in(parent[key], draw(st.sampled_from([1, 2, 31, 32, 40])))
    return doc


OPERATIONS = ["tweak"] * 4 + ["replace", "drop", "add", "retype", "scale", "nest"]
"""Mostly type-preserving tweaks: a value of the right type but an extreme size gets past the
type checks, deeper into the loader and into the replay."""


def _same_type(value: Any) -> st.SearchStrategy[Any]:
    if isinstance(value, bool):
        return st.booleans()
    if isinstance(value, int | float):
        return st.sampled_from(EXTREME_NUMBERS) | st.integers() | st.floats() | st.just(
            HUGE_INTEGER)
    if isinstance(value, str):
        return st.sampled_from(STRINGS) | st.text(max_size=12)
    if isinstance(value, list):
        return st.lists(st.sampled_from(EXTREME_NUMBERS) | st.floats(), max_size=8) | st.just(
            [v for v in value for _ in range(2)])
    return values()


def _scaled(value: float, factor: float) -> float:
    try:
        return value * factor
    except OverflowError:  # an integer too large for a float, times a float
        return math.inf


def _retyped(value: Any) -> Any:
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, int | float):
        return str(value)
    if isinstance(value, str):
        return [value]
    if isinstance(value, list):
        return {str(i): v for i, v in enumerate(value)}
    if isinstance(value, dict):
        return list(value.values())
    return 0


def _nested_in(value: Any, depth: int) -> Any:
    for _ in range(depth):
        value = [value]
    return value


def to_json(doc: Any) -> str:
    text = json.dumps(doc, default=str, allow_nan=True, ensure_ascii=True)
    for marker, literal in MARKERS.items():
        text = text.replace(json.dumps(marker), literal)
    return text


def to_toml(doc: Any) -> str:
    """``doc`` as TOML: every top-level key one line, tables inline (None values dropped)."""
    if not isinstance(doc, dict):
        return f"value = {_toml_value(doc)}\n"
    lines = [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in doc.items() if v is not None]
    return "\n".join(lines) + "\n"


def _toml_key(key: Any) -> str:
    return json.dumps(str(key), ensure_ascii=True)


def _toml_value(value: Any) -> str:
    if isinstance(value, str) and value in MARKERS:
        return MARKERS[value]
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value) if value.bit_length() < 4000 else MARKERS[HUGE_INTEGER]
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if (
            math.isinf(value)) else repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=True)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value if v is not None) + "]"
    if isinstance(value, dict):
        items = (f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items() if v is not None)
        return "{" + ", ".join(items) + "}"
    return json.dumps(str(value))


@st.composite
def byte_mutated(draw: st.DrawFn, data: bytes) -> bytes:
    """``data`` with a few byte-level changes: a flip, an insertion (invalid UTF-8 among
    them), a deletion, a cut, a repeated slice."""
    data = bytearray(data)
    for _ in range(draw(st.integers(1, 3))):
        if not data:
            data += draw(st.binary(min_size=1, max_size=8))
            continue
        at = draw(st.integers(0, len(data) - 1))
        operation = draw(st.sampled_from(["flip", "insert", "delete", "cut", "repeat"]))
        if operation == "flip":
            data[at] ^= 1 << draw(st.integers(0, 7))
        elif operation == "insert":
            data[at:at] = draw(st.sampled_from([b"\xff", b"\xc3", b"\xed\xa0\x80", b"\x00",
                                                b"[", b"{", b"\"", b"9" * 30, b"\n"])
                               | st.binary(max_size=8))
        elif operation == "delete":
            del data[at:at + draw(st.integers(1, 16))]
        elif operation == "cut":
            del data[at:]
        else:
            data[at:at] = data[at:at + draw(st.integers(1, 64))]
    return bytes(data)
