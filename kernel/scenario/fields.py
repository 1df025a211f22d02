"""Typed reads from parsed JSON or TOML that fail with the file, the place and the field named.

Every read checks the type and the range: a number is finite and, where the caller gives them,
within ``minimum``/``maximum`` (the bounds in :mod:`kernel.scenario.bounds`); an integer is
64-bit. A value is shown in a message through :func:`shown`, which never fails and never floods
the terminal (a 4000-digit integer or a megabyte string is summarised).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from drivers import settings
from drivers.settings import SHOWN_CHARS, SettingsError, one_line, printable, shown

MAX_MAGNITUDE = 1e13
"""No field is legitimately this large (as milliseconds: three centuries); larger values
overflow the integer-nanosecond clock, so they are refused here with the field named."""


class ScenarioError(SettingsError):
    """A file that is not a valid scenario; ``str()`` names the file, the place and the field."""


class Where(settings.Where):
    """A place in a scenario or a manifest; its errors are :class:`ScenarioError`."""

    __slots__ = ()

    def error(self, message: str) -> ScenarioError:
        return ScenarioError(self.message(message))


def is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _finite(value: Any) -> bool:
    """A number that is finite and within MAX_MAGNITUDE (an int never reaches math here, so a
    huge one cannot overflow a float conversion)."""
    if isinstance(value, int):
        return abs(value) <= MAX_MAGNITUDE
    return math.isfinite(value) and abs(value) <= MAX_MAGNITUDE


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
    minimum: float | None = None, positive: bool = False, maximum: float | None = None,
) -> float:
    if key not in parent or parent[key] is None:
        if default is None:
            raise where.error(f"missing required key {key!r}")
        return default
    value = parent[key]
    here = where.at(key)
    if not is_number(value) or (isinstance(value, float) and not math.isfinite(value)):
        raise here.error(f"must be a finite number, got {shown(value)}")
    if not _finite(value):
        raise here.error(f"must be at most {MAX_MAGNITUDE:g} in magnitude, got {shown(value)}")
    in_range(float(value), here, minimum, maximum, positive)
    return float(value)


def in_range(
    value: float, where: Where, minimum: float | None = None, maximum: float | None = None,
    positive: bool = False, why: str = "",
) -> None:
    """Refuse ``value`` outside ``[minimum, maximum]`` (or not > 0 with ``positive``); ``why``
    says where a bound comes from when it is not a constant."""
    because = f" ({why})" if why else ""
    if positive and value <= 0:
        raise where.error(f"must be positive, got {shown(value)}")
    if minimum is not None and value < minimum:
        raise where.error(f"must be at least {minimum:g}{because}, got {shown(value)}")
    if maximum is not None and value > maximum:
        raise where.error(f"must be at most {maximum:g}{because}, got {shown(value)}")


def integer(
    parent: Mapping[str, Any], key: str, where: Where, default: int | None = None,
    minimum: int | None = None, maximum: int | None = None,
) -> int:
    if key not in parent or parent[key] is None:
        if default is None:
            raise where.error(f"missing required key {key!r}")
        return default
    value = parent[key]
    if isinstance(value, float) and value.is_integer() and abs(value) <= MAX_MAGNITUDE:
        value = int(value)
    if not isinstance(value, int) or isinstance(value, bool):
        raise where.at(key).error(f"must be an integer, got {shown(value)}")
    if minimum is not None and value < minimum:
        raise where.at(key).error(f"must be at least {minimum}, got {shown(value)}")
    if maximum is not None and value > maximum:
        raise where.at(key).error(f"must be at most {maximum}, got {shown(value)}")
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
    raise where.at(key).error(f"must be a non-empty string, got {shown(value)}")


def flag(parent: Mapping[str, Any], key: str, where: Where, default: bool) -> bool:
    value = parent.get(key, default)
    if not isinstance(value, bool):
        raise where.at(key).error(f"must be true or false, got {shown(value)}")
    return value


def choice(
    parent: Mapping[str, Any], key: str, where: Where, options: Sequence[str],
    default: str | None = None,
) -> str:
    value = text(parent, key, where, default)
    if value not in options:
        raise where.at(key).error(
            f"unknown value {shown(value)} (expected one of {', '.join(options)})")
    return value


def vector(
    value: Any, where: Where, length: int | None = None, finite: bool = True,
    bound: float | None = None,
) -> list:
    """A list of numbers; with ``finite`` every one finite, with ``bound`` every one within
    ``[-bound, bound]`` (infinities, where allowed, are not checked against it)."""
    if not isinstance(value, list) or not all(is_number(v) for v in value):
        raise where.error("must be a list of numbers")
    if length is not None and len(value) != length:
        raise where.error(f"has {len(value)} values, expected {length}")
    for index, item in enumerate(value):
        if isinstance(item, int) and abs(item) > MAX_MAGNITUDE:
            raise where.at(index).error(
                f"must be at most {MAX_MAGNITUDE:g} in magnitude, got {shown(item)}")
        if finite and not math.isfinite(item):
            raise where.error("must hold finite numbers only")
        if bound is not None and math.isfinite(item) and abs(item) > bound:
            raise where.at(index).error(f"must be within ±{bound:g}, got {shown(item)}")
    return [float(v) for v in value]


__all__ = ["MAX_MAGNITUDE", "SHOWN_CHARS", "ScenarioError", "Where", "choice", "flag",
           "in_range", "integer", "is_number", "mapping", "number", "one_line", "printable",
           "shown", "text", "vector"]
