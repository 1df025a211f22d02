"""Every numeric setting of ``[policy]`` and of each vendor driver, set to every extreme value:
refused with a ``SettingsError`` naming the key, or usable: loaded as the file gives it, finite,
inside its documented range, and computed with as a run does (:mod:`tests.fuzz.settings_use`).

The property tests of ``test_property_loaders.py`` draw a few of these combinations through
the whole of ``warden run``'s checks; this sweep tries all of them against the settings tables
alone (microseconds each), so that no key is left to chance.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import typing
from pathlib import Path
from typing import Any

import msgspec
import pytest

from drivers.settings import SettingsError, settings_from_mapping
from kernel.scenario.fields import ScenarioError, Where
from kernel.shell.link_settings import PolicySettings
from kernel.tables import bounds_of, read_table
from tests.fuzz.settings_use import (
    ADDRESS_STAND_INS,
    DRIVER_SETTINGS,
    use_driver_settings,
    use_policy,
)

ROOT = Path(__file__).resolve().parents[2]
PERIOD_S = 0.002
EXTREMES: list[Any] = [
    0, -1, 1, 2, 0.5, -0.0, 1e-9, 1e-300, 5e-324, 7.0, 1e3, 65535, 65536, 1e6, 2**31, 1e12,
    2**53 + 1, 2**63 - 1, -(2**63), 1e300, 1.7e308, -1e300, math.inf, -math.inf, math.nan,
]
"""Numbers TOML can hold: zero, signs, the subnormal, the 16/32/64-bit edges, inf and NaN."""
MAGNITUDE_MAX = 1e12
"""No accepted driver or link setting comes near this (the largest, a gripper's counts per
metre, stays below 2.6e10): a value beyond it got through unbounded."""


def _assert_bounded(settings: Any) -> None:
    fields = (msgspec.structs.fields(settings) if isinstance(settings, msgspec.Struct)
              else dataclasses.fields(settings))
    for field in fields:
        value = getattr(settings, field.name)
        for number in value if isinstance(value, tuple) else (value,):
            if isinstance(number, int | float) and not isinstance(number, bool):
                assert math.isfinite(number) and abs(number) <= MAGNITUDE_MAX, (
                    f"{field.name} = {value} was accepted")


def _assert_usable(settings: Any, key: str, value: Any) -> None:
    """What "usable" means for a setting the loader accepted: the loaded value is the file's
    (not a default put in its place), finite and bounded, inside the key's documented range
    where it has one; then the run's own arithmetic on it (``use_*``) does not fail. A loader
    that accepts everything, or swaps what it cannot take for a default, fails here."""
    loaded = getattr(settings, key)
    assert loaded == (tuple(value) if isinstance(value, list) else value), (
        f"{key} = {value!r} was accepted as {loaded!r}")
    _assert_bounded(settings)
    if isinstance(settings, PolicySettings):
        low, high = bounds_of(PolicySettings, key)
        assert low is not None and high is not None, f"{key} declares no range"
        assert low <= loaded <= high, f"{key} = {loaded!r} is outside [{low}, {high}]"


def _shipped_tables() -> dict[str, dict[str, Any]]:
    tables = {}
    for path in sorted((ROOT / "manifests").glob("*.toml")):
        table = dict(tomllib.loads(path.read_text())["driver"])
        name = table.pop("name")
        if name in DRIVER_SETTINGS:
            tables[name] = {**ADDRESS_STAND_INS[name], **table}
    return tables


SHIPPED = _shipped_tables()


def _numeric_fields(cls: type) -> list[tuple[str, bool]]:
    """(name, is a list) of every field holding numbers (booleans and strings left out)."""
    hints = typing.get_type_hints(cls)
    found = []
    fields = (msgspec.structs.fields(cls) if issubclass(cls, msgspec.Struct)
              else dataclasses.fields(cls))
    for field in fields:
        hint = hints[field.name]
        args = typing.get_args(hint)
        if hint in (int, float) or (set(args) & {int, float} and type(None) in args):
            found.append((field.name, False))
        elif typing.get_origin(hint) is tuple and args and args[0] in (int, float):
            found.append((field.name, True))
    return found


def _values(base: dict[str, Any], key: str, is_list: bool, count: int) -> list[Any]:
    if not is_list:
        return EXTREMES
    length = len(base.get(key) or []) or count
    return [[value] * length for value in EXTREMES] + [
        [*base[key][:-1], value] for value in EXTREMES if base.get(key)]


CASES = [(driver, key, is_list) for driver, cls in DRIVER_SETTINGS.items()
         for key, is_list in _numeric_fields(cls)]


@pytest.mark.parametrize(("driver", "key", "is_list"), CASES,
                         ids=[f"{d}.{k}" for d, k, _ in CASES])
def test_every_driver_setting_is_refused_or_usable(driver: str, key: str, is_list: bool) -> None:
    base = SHIPPED[driver]
    joints = len(base.get("node_ids") or base.get("ids") or [0] * 6)
    cls = DRIVER_SETTINGS[driver]
    for value in _values(base, key, is_list, joints):
        try:
            settings = settings_from_mapping(cls, {**base, key: value}, "cell.toml: driver")
        except SettingsError as error:
            assert str(error).startswith("cell.toml: driver"), error
            continue
        _assert_usable(settings, key, value)
        use_driver_settings(settings, PERIOD_S)


POLICY_KEYS = [name for name, _ in _numeric_fields(PolicySettings)]
"""Every numeric key of ``[policy]``: each declares its range on its field."""


@pytest.mark.parametrize("key", POLICY_KEYS)
def test_every_policy_link_setting_is_refused_or_usable(key: str) -> None:
    for value in EXTREMES:
        try:
            settings = read_table(PolicySettings, {key: value}, Where("cell.toml", "policy"))
        except ScenarioError as error:
            assert str(error).startswith("cell.toml: policy"), error
            continue
        _assert_usable(settings, key, value)
        use_policy(settings, 2_000_000)


def test_the_shipped_settings_are_usable() -> None:
    for driver, table in SHIPPED.items():
        use_driver_settings(settings_from_mapping(DRIVER_SETTINGS[driver], table, driver),
                            PERIOD_S)
    use_policy(PolicySettings(), 2_000_000)
