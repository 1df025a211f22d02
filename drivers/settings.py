"""Settings tables read into frozen msgspec Structs, each field's bounds checked: the one mechanism.

Every table of a manifest, a driver's ``[driver]`` as much as warden's own ``[policy]`` or the
monitor's ``[safety]``, has a frozen Struct type declared beside the component that uses it, and
each numeric field carries its range once, on the field itself::

    servo_gain: Annotated[float, Meta(ge=100.0, le=2000.0)] = 300.0

:func:`read_table` is the one reader: unknown keys, missing required keys, values of the wrong
type and values out of range each fail with ``file: table.key: why`` (the CLI exits 2). The same
``Meta`` is enforced by msgspec when a journal's header is decoded and, through
:class:`Settings`, when code builds a settings value itself, so a bound is never written twice.
Rules across fields (a heartbeat period shorter than its timeout) live in the Struct's
``__post_init__``; its ``ValueError`` is reported naming the table.

This module sits in ``drivers`` because it is the lowest layer both readers share: a driver
declares its settings type with it, and ``kernel`` (which may import ``drivers``, never the
reverse: tests/test_layers.py) reads every other table with it.
"""

from __future__ import annotations

import functools
import math
import re
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, TypeVar

import msgspec

T = TypeVar("T", bound=msgspec.Struct)
SHOWN_CHARS = 60
"""A value quoted in a message is cut to this many characters."""


class SettingsError(ValueError):
    """A table that does not fit its settings type; ``str()`` names the file, the table and
    the key (``cell.toml: driver.servo_gain: must be at least 100, got 50.0``)."""


class KeyProblem(ValueError):
    """What a settings type's ``__post_init__`` raises for a rule across fields that one key
    answers for: :func:`read_table` names that key (``task.gripper_open: must exceed ...``)."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}")
        self.key, self.message = key, message


@dataclass(frozen=True, slots=True)
class Where:
    """A place in a file: ``file`` and the dotted ``path`` of a key in it. ``file`` may be
    empty when the caller names the table itself (``drivers.arm``)."""

    file: str
    path: str

    def at(self, key: str | int) -> typing.Self:
        if isinstance(key, int):
            part = f"[{key}]"
        else:
            name = printable(key)
            part = f".{name}" if self.path else name
        return type(self)(self.file, f"{self.path}{part}")

    def note(self, text: str) -> typing.Self:
        """The same place with a note, e.g. an event's kind: ``events[3] (state)``."""
        return type(self)(self.file, f"{self.path} ({printable(text)})")

    def message(self, text: str) -> str:
        file = f"{self.file}: " if self.file else ""
        place = f"{self.path}: " if self.path else ""
        return f"{file}{place}{one_line(text)}"

    def error(self, message: str) -> SettingsError:
        return SettingsError(self.message(message))


def one_line(text: str) -> str:
    """``text`` with every unprintable character escaped (a message quoting a file's text, a
    model path with a newline, stays one line)."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def printable(name: str) -> str:
    """A key as it appears in a place: as written when it is plain text, quoted with escapes
    when it holds a newline or another unprintable character (a message stays one line), cut
    short when long."""
    text = name if name.isprintable() else repr(name)
    return text if len(text) <= SHOWN_CHARS else f"{text[:SHOWN_CHARS]}..."


def shown(value: Any) -> str:
    """``repr(value)`` cut short, safe for any value a parser can produce."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 64:
        try:
            return f"an integer of {len(str(abs(value)))} digits"
        except ValueError:  # beyond the interpreter's digit limit for int-to-text conversion
            return f"an integer of about {int(value.bit_length() * math.log10(2)) + 1} digits"
    text = repr(value)
    return text if len(text) <= SHOWN_CHARS else f"{text[:SHOWN_CHARS]}..."


class Settings(msgspec.Struct, frozen=True):
    """Base of a settings type whose value code may also build itself (a test, an emulator's
    launcher): the fields' ``Meta`` bounds are checked on construction too, by the same
    :func:`check_bounds`. A subclass's ``__post_init__`` calls this one first."""

    def __post_init__(self) -> None:
        where = Where("", "")
        for name, metas in _bounded_fields(type(self)):
            check_value(getattr(self, name), metas, where.at(name))


@functools.cache
def _bounded_fields(cls: type) -> tuple[tuple[str, tuple[Any, ...]], ...]:
    hints = typing.get_type_hints(cls, include_extras=True)
    return tuple((f.name, _metas_within(hints[f.name])) for f in msgspec.structs.fields(cls)
                 if _metas_within(hints[f.name]))


def _metas_within(hint: Any) -> tuple[Any, ...]:
    """The bounds of ``hint`` wherever they sit: on it, on an optional arm, on tuple items."""
    base, metas = _split(hint)
    if metas:
        return tuple(metas)
    if typing.get_origin(base) in (typing.Union, _UnionType):
        return tuple(m for arm in typing.get_args(base) for m in _metas_within(arm))
    if typing.get_origin(base) is tuple:
        return tuple(m for arm in typing.get_args(base) if arm is not Ellipsis
                     for m in _metas_within(arm))
    return ()


def check_value(value: Any, metas: tuple[Any, ...], where: Where) -> None:
    """``value`` (or each item of a tuple, at any depth) within every one of ``metas``."""
    if isinstance(value, tuple):
        for index, item in enumerate(value):
            check_value(item, metas, where.at(index))
        return
    for meta in metas:
        check_bounds(value, meta, where)


def read_table(cls: type[T], table: Mapping[str, Any], where: Where | str) -> T:
    """Build the Struct ``cls`` from the table ``table`` (at ``where``: a place, or the table's
    name as a message starts it, ``"cell.toml: driver"``).

    Raises:
        SettingsError: (the subclass ``where.error`` makes) naming ``file: table.key``, for an
            unknown or missing key, a wrong type, a value out of its declared range, or a rule
            across fields that ``cls`` refuses.
    """
    where = Where("", where) if isinstance(where, str) else where
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
    except KeyProblem as problem:
        raise where.at(problem.key).error(problem.message) from None
    except (TypeError, ValueError) as error:
        raise where.error(str(error)) from None


settings_from_mapping = read_table
"""The name the drivers' settings reader had (same function)."""


def typed(value: Any, hint: Any, where: Where) -> Any:
    """``value`` as the type ``hint`` (strictly: no string for a number, no float for an
    integer, no bool for either), checked against the ``Meta`` bounds ``hint`` declares."""
    base, metas = _split(hint)
    if typing.get_origin(base) in (typing.Union, _UnionType):
        return _typed_union(value, typing.get_args(base), where)
    if typing.get_origin(base) is tuple:
        return _typed_tuple(value, typing.get_args(base), where)
    if isinstance(base, type) and issubclass(base, msgspec.Struct):  # a table inside a table
        if not isinstance(value, Mapping):
            raise where.error(f"expected a table, got {shown(value)}")
        return read_table(base, value, where)
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


def _typed_union(value: Any, arms: tuple[Any, ...], where: Where) -> Any:
    """An optional value (``X | None``): None as written, else the other arm's."""
    if value is None and type(None) in arms:
        return None
    others = [arm for arm in arms if arm is not type(None)]
    if len(others) != 1:
        raise TypeError(f"a settings field is X or X | None, not a union of {others}")
    return typed(value, others[0], where)


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
    """The one range check: a finite number within ``meta``'s ``ge``/``gt``/``le``, a text
    within its ``min_length``/``max_length`` and matching its ``pattern``."""
    if isinstance(value, str):
        _check_length(value, meta, where)
        return
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


def _check_length(value: str, meta: msgspec.Meta, where: Where) -> None:
    if meta.min_length is not None and len(value) < meta.min_length:
        raise where.error("must not be empty" if meta.min_length == 1 else
                          f"must be at least {meta.min_length} characters, got {len(value)}")
    if meta.max_length is not None and len(value) > meta.max_length:
        raise where.error(f"must be at most {meta.max_length} characters, got {len(value)}")
    if meta.pattern is not None and re.search(meta.pattern, value) is None:
        raise where.error(f"must match {meta.pattern}, got {shown(value)}")


def _number(bound: float) -> str:
    """A bound as a reader writes it: an integer in full (1048576, not 1.04858e+06)."""
    return str(bound) if isinstance(bound, int) else f"{bound:g}"


def bounds_of(cls: type, name: str) -> tuple[float | None, float | None]:
    """The (lowest, highest) value the field ``name`` of ``cls`` declares (tests, docs)."""
    metas = _metas_within(typing.get_type_hints(cls, include_extras=True)[name])
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


_UnionType = type(int | None)

__all__ = ["KeyProblem", "Settings", "SettingsError", "Where", "bounds_of", "check_bounds",
           "read_table", "settings_from_mapping", "shown", "typed"]
