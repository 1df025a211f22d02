"""Drivers by manifest name: a table of import paths plus the ``warden.drivers`` entry points.

Nothing is imported until a manifest asks for it, so a robot PC without one vendor SDK can still
run the others. No if/elif chain: adding a driver is one line here or one entry point.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from importlib.metadata import entry_points
from typing import Any

from drivers.base import Driver
from drivers.settings import SettingsError, Where, read_table

BUILTIN: dict[str, str] = {
    "sim": "drivers.sim.driver:SimDriver",
    "ur_rtde": "drivers.ur_rtde.driver:URRTDEDriver",
    "dynamixel": "drivers.dynamixel.driver:DynamixelDriver",
    "canopen402": "drivers.canopen402.driver:CiA402Driver",
}

BUILTIN_SETTINGS: dict[str, str] = {
    "ur_rtde": "drivers.ur_rtde.settings:URSettings",
    "dynamixel": "drivers.dynamixel.settings:DynamixelSettings",
    "canopen402": "drivers.canopen402.settings:CiA402Settings",
}
"""Where a built-in vendor driver's settings type lives (its module also has ``ADDRESS_KEYS``):
a reader of ``[driver]`` such as the safety monitor decodes the table without loading the driver
and what the driver relies on of warden's core (tests/drivers/test_registry_settings.py keeps
these equal to the driver classes' own)."""


class UnknownDriver(LookupError):
    pass


def available() -> dict[str, str]:
    """Every known driver name and where it lives (built-ins, then entry points)."""
    table = dict(BUILTIN)
    for point in entry_points(group="warden.drivers"):
        table.setdefault(point.name, point.value)
    return table


def load(name: str) -> type[Driver]:
    """The driver class registered under ``name``.

    Raises:
        UnknownDriver: no driver has that name, or what is registered is not a
            :class:`drivers.base.Driver`.
    """
    table = available()
    if name not in table:
        known = ", ".join(sorted(table))
        raise UnknownDriver(f"unknown driver {name!r}; known drivers: {known}")
    module_name, _, attribute = table[name].partition(":")
    found = getattr(importlib.import_module(module_name), attribute)
    if not (isinstance(found, type) and issubclass(found, Driver)):
        raise UnknownDriver(f"driver {name!r} ({table[name]}) is not a drivers.base.Driver: "
                            "subclass it to declare the driver contract")
    return found


def settings_for(name: str, table: Mapping[str, Any], where: Where | str, *,
                 address_filled_in: bool = False) -> Any:
    """The ``[driver]`` table (without ``name``) decoded into the settings type the driver
    ``name`` declares, checked once: unknown keys, types and bounds.

    ``address_filled_in``: the run fills in the device's address itself (an emulator it
    launches), so the driver's ``address_keys`` may be missing: they are checked with their
    placeholders.

    Raises:
        UnknownDriver: no driver has that name.
        SettingsError: naming ``where.key`` (the subclass ``where`` makes: a
            ``ScenarioError`` for the manifest loader's place).
    """
    settings_type, address_keys = declared_settings(name)
    if address_filled_in:
        table = {**address_keys, **table}
    return read_table(settings_type, table, where)


def declared_settings(name: str) -> tuple[type[Any], Mapping[str, Any]]:
    """The settings type and the address keys the driver ``name`` declares; a built-in's
    without importing the driver (:data:`BUILTIN_SETTINGS`)."""
    if name in BUILTIN_SETTINGS and name in BUILTIN and available()[name] == BUILTIN[name]:
        module_name, _, attribute = BUILTIN_SETTINGS[name].partition(":")
        module = importlib.import_module(module_name)
        return getattr(module, attribute), module.ADDRESS_KEYS
    driver = load(name)
    return driver.settings_type, driver.address_keys


__all__ = ["BUILTIN", "BUILTIN_SETTINGS", "SettingsError", "UnknownDriver", "available",
           "declared_settings", "load", "settings_for"]
