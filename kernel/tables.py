"""Manifest tables read into their frozen msgspec Structs, each field's bounds checked.

A table's type is declared beside the component that uses it (``[policy]`` in
:mod:`kernel.shell.link_settings`, ``[cell]``, ``[trial]``... in :mod:`kernel.settings`), and
each numeric field carries its range once, on the field itself::

    max_chunks_per_s: Annotated[float, Meta(ge=0.1, le=10_000.0)] = 100.0

:func:`read_table` is the one mechanism that checks them while a manifest loads: unknown keys,
missing required keys, values of the wrong type and values out of range each fail with
``file: table.key: why`` (the CLI exits 2). msgspec enforces the same ``Meta`` when a journal's
header is decoded, so a bound is never written twice. Cross-field rules (a heartbeat timeout
longer than its interval) live in the Struct's ``__post_init__``: they name the table.
"""

from __future__ import annotations

import math
import typing
from collections.abc import Mapping
from enum import StrEnum
from typing import Any, TypeVar

import msgspec

from kernel.scenario.fields import Where, shown

T = TypeVar("T", bound=msgspec.Struct)


def read_table(cls: type[T], table: Mapping[str, Any], where: Where) -> T:
    """Build the Struct ``cls`` from the manifest table ``table`` (at ``where``).

    Raises:
        ScenarioError: naming ``file: table.key`` (the manifest loader makes it a
            ManifestError), for an unknown or missing key, a wrong type or a value out of
            its declared range.
    """
    fields = msgspec.structs.fields(cls)
    known = {f.name for f in fields}
    for key in table:
        if key not in known:
            raise where.at(key).error(f"unknown key (known: {', '.join(f.name for f in fields)})")
    hints = typing.get_type_hints(cls, include_extras=True)
    values: dict[str, Any] = {}
    for field in fields:
        if field.name in table:
            values[field.name] = typed(table[field.name], hints[field.name],
                                       where.at(field.name))
        elif field.required:
            raise where.at(field.name).error("required key is missing")
    try:
        return cls(**values)
    except (TypeError, ValueError) as error:
        raise where.error(str(error)) from None


def typed(value: Any, hint: Any, where: Where) -> Any:
    """``value`` as the type ``hint`` (strictly: no string for a number, no float for an
    integer, no bool for either), checked against the ``Meta`` bounds ``hint`` declares."""
    base, metas = _split(hint)
    if typing.get_origin(base) is tuple:
        return _typed_tuple(value, typing.get_args(base), where)
    try:
        result = msgspec.convert(value, base, strict=True)
    except msgspec.ValidationError:
        if isinstance(base, type) and issubclass(base, StrEnum) and isinstance(value, str):
            raise where.error(f"unknown value {shown(value)} (expected one of "
                              f"{', '.join(base)})") from None
        raise where.error(f"expected {_name(base)}, got {shown(value)}") from None
    for meta in metas:
        check_bounds(result, meta, where)
    return result


def _typed_tuple(value: Any, args: tuple[Any, ...], where: Where) -> tuple[Any, ...]:
    if not isinstance(value, list | tuple):
        raise where.error(f"expected a list, got {shown(value)}")
    if len(args) == 2 and args[1] is Ellipsis:
        args = (args[0],) * len(value)
    elif len(args) != len(value):
        raise where.error(f"has {len(value)} values, expected {len(args)}")
    return tuple(typed(item, hint, where.at(index))
                 for index, (hint, item) in enumerate(zip(args, value, strict=True)))


def check_bounds(value: Any, meta: msgspec.Meta, where: Where) -> None:
    """The one range check: a finite number within ``meta``'s ``ge``/``gt``/``le``."""
    if not isinstance(value, int | float) or isinstance(value, bool):
        return
    high = meta.le
    if not math.isfinite(value):
        limit = f" of at most {_number(high)}" if high is not None else ""
        raise where.error(f"must be a finite number{limit}, got {shown(value)}")
    if meta.gt is not None and not value > meta.gt:
        above = "positive" if meta.gt == 0 else f"above {_number(meta.gt)}"
        raise where.error(f"must be {above}, got {shown(value)}")
    if meta.ge is not None and value < meta.ge:
        raise where.error(f"must be at least {_number(meta.ge)}, got {shown(value)}")
    if high is not None and value > high:
        raise where.error(f"must be at most {_number(high)}, got {shown(value)}")


def _number(bound: float) -> str:
    """A bound as a reader writes it: an integer in full (1048576, not 1.04858e+06)."""
    return str(bound) if isinstance(bound, int) else f"{bound:g}"


def bounds_of(cls: type, name: str) -> tuple[float | None, float | None]:
    """The (lowest, highest) value the field ``name`` of ``cls`` declares (tests, docs)."""
    _, metas = _split(typing.get_type_hints(cls, include_extras=True)[name])
    low = next((m.ge if m.ge is not None else m.gt for m in metas
                if m.ge is not None or m.gt is not None), None)
    return low, next((m.le for m in metas if m.le is not None), None)


def _split(hint: Any) -> tuple[Any, list[msgspec.Meta]]:
    if typing.get_origin(hint) is typing.Annotated:
        base, *extras = typing.get_args(hint)
        return base, [e for e in extras if isinstance(e, msgspec.Meta)]
    return hint, []


def _name(hint: Any) -> str:
    return getattr(hint, "__name__", None) or str(hint)
