"""Driver settings from a manifest table: frozen dataclasses, unknown keys refused by name."""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from typing import Any, TypeVar

T = TypeVar("T")


class SettingsError(ValueError):
    """A manifest table does not fit a driver's settings; the message names the key."""


def configured(cls: type, table: Mapping[str, Any], key: str) -> Any:
    """The value ``table`` gives ``key``, else the default of ``cls``'s field (no coercion:
    for a look at one setting before the whole table is checked)."""
    if key in table:
        return table[key]
    field = {f.name: f for f in dataclasses.fields(cls)}[key]  # type: ignore[arg-type]
    return field.default


def settings_from_mapping(cls: type[T], table: Mapping[str, Any], where: str) -> T:
    """Build the frozen dataclass ``cls`` from ``table``; ``where`` names the table in errors.

    Unknown keys, missing required keys and values of the wrong type raise
    :class:`SettingsError` naming ``where.key``.
    """
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise SettingsError(f"{where}.{unknown[0]}: unknown key (known: {', '.join(fields)})")
    hints = typing.get_type_hints(cls)
    values: dict[str, Any] = {}
    for name, field in fields.items():
        if name not in table:
            if field.default is dataclasses.MISSING and field.default_factory is (
                dataclasses.MISSING
            ):
                raise SettingsError(f"{where}.{name}: required key is missing")
            continue
        values[name] = _coerce(table[name], hints[name], f"{where}.{name}")
    try:
        return cls(**values)
    except (TypeError, ValueError) as error:
        raise SettingsError(f"{where}: {error}") from error


def _coerce(value: Any, hint: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        for option in typing.get_args(hint):
            try:
                return _coerce(value, option, where)
            except SettingsError:
                continue
        raise SettingsError(f"{where}: {value!r} does not fit {hint}")
    if origin is tuple:
        return _coerce_tuple(value, typing.get_args(hint), where)
    if hint is type(None):
        if value is None:
            return None
        raise SettingsError(f"{where}: expected nothing, got {value!r}")
    if hint is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(hint, type) and isinstance(value, hint) and not (
        hint is int and isinstance(value, bool)
    ):
        return value
    if isinstance(hint, type) and issubclass(hint, str) and isinstance(value, str):
        try:
            return hint(value)
        except ValueError:
            raise SettingsError(f"{where}: unknown value {value!r}") from None
    raise SettingsError(f"{where}: expected {getattr(hint, '__name__', hint)}, got {value!r}")


def _coerce_tuple(value: Any, args: tuple[Any, ...], where: str) -> tuple[Any, ...]:
    if not isinstance(value, list | tuple):
        raise SettingsError(f"{where}: expected a list, got {value!r}")
    if len(args) == 2 and args[1] is Ellipsis:
        return tuple(_coerce(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
    if len(args) != len(value):
        raise SettingsError(f"{where}: expected {len(args)} values, got {len(value)}")
    pairs = enumerate(zip(args, value, strict=True))
    return tuple(_coerce(item, hint, f"{where}[{i}]") for i, (hint, item) in pairs)
