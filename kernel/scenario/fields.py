"""Typed reads from parsed JSON that fail with the file, the place and the field named."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

MAX_MAGNITUDE = 1e13
"""No field is legitimately this large (as milliseconds: three centuries); larger values
overflow the integer-nanosecond clock, so they are refused here with the field named."""


class ScenarioError(ValueError):
    """A file that is not a valid scenario; ``str()`` names the file, the place and the field."""


@dataclass(frozen=True, slots=True)
class Where:
    file: str
    path: str

    def at(self, key: str | int) -> Where:
        part = f"[{key}]" if isinstance(key, int) else (f".{key}" if self.path else key)
        return Where(self.file, f"{self.path}{part}")

    def error(self, message: str) -> ScenarioError:
        place = f"{self.path}: " if self.path else ""
        return ScenarioError(f"{self.file}: {place}{message}")


def is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def mapping(parent: Mapping[str, Any], key: str, where: Where, required: bool = True) -> dict:
    if key not in parent:
        if required:
            raise where.error(f"missing required key {key!r}")
        return {}
    value = parent[key]
    if not isinstance(value, dict):
        raise where.at(key).error(f"must be an object, got {type(value).__name__}")
    return value


def number(
    parent: Mapping[str, Any], key: str, where: Where, default: float | None = None,
    minimum: float | None = None, positive: bool = False,
) -> float:
    if key not in parent or parent[key] is None:
        if default is None:
            raise where.error(f"missing required key {key!r}")
        return default
    value = parent[key]
    here = where.at(key)
    if not is_number(value) or not math.isfinite(value):
        raise here.error(f"must be a finite number, got {value!r}")
    if abs(value) > MAX_MAGNITUDE:
        raise here.error(f"must be at most {MAX_MAGNITUDE:g} in magnitude, got {value!r}")
    if positive and value <= 0:
        raise here.error(f"must be positive, got {value!r}")
    if minimum is not None and value < minimum:
        raise here.error(f"must be at least {minimum}, got {value!r}")
    return float(value)


def integer(
    parent: Mapping[str, Any], key: str, where: Where, default: int | None = None,
    minimum: int | None = None,
) -> int:
    if key not in parent or parent[key] is None:
        if default is None:
            raise where.error(f"missing required key {key!r}")
        return default
    value = parent[key]
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, int) or isinstance(value, bool):
        raise where.at(key).error(f"must be an integer, got {value!r}")
    if minimum is not None and value < minimum:
        raise where.at(key).error(f"must be at least {minimum}, got {value!r}")
    return value


def text(
    parent: Mapping[str, Any], key: str, where: Where, default: str | None = None,
    numbers_ok: bool = True,
) -> str:
    if key not in parent or parent[key] is None:
        if default is None:
            raise where.error(f"missing required key {key!r}")
        return default
    value = parent[key]
    if isinstance(value, str) and value:
        return value
    if numbers_ok and isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    raise where.at(key).error(f"must be a non-empty string, got {value!r}")


def flag(parent: Mapping[str, Any], key: str, where: Where, default: bool) -> bool:
    value = parent.get(key, default)
    if not isinstance(value, bool):
        raise where.at(key).error(f"must be true or false, got {value!r}")
    return value


def choice(
    parent: Mapping[str, Any], key: str, where: Where, options: Sequence[str],
    default: str | None = None,
) -> str:
    value = text(parent, key, where, default)
    if value not in options:
        raise where.at(key).error(f"unknown value {value!r} (expected one of {', '.join(options)})")
    return value


def vector(value: Any, where: Where, length: int | None = None, finite: bool = True) -> list:
    if not isinstance(value, list) or not all(is_number(v) for v in value):
        raise where.error("must be a list of numbers")
    if finite and not all(math.isfinite(v) for v in value):
        raise where.error("must hold finite numbers only")
    if length is not None and len(value) != length:
        raise where.error(f"has {len(value)} values, expected {length}")
    return [float(v) for v in value]
