"""Drivers by manifest name: a table of import paths plus the ``warden.drivers`` entry points.

Nothing is imported until a manifest asks for it, so a robot PC without one vendor SDK can still
run the others. No if/elif chain: adding a driver is one line here or one entry point.
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from typing import Any

BUILTIN: dict[str, str] = {
    "sim": "drivers.sim.driver:SimDriver",
    "ur_rtde": "drivers.ur_rtde.driver:URRTDEDriver",
    "dynamixel": "drivers.dynamixel.driver:DynamixelDriver",
    "canopen402": "drivers.canopen402.driver:CiA402Driver",
}


class UnknownDriver(LookupError):
    pass


def available() -> dict[str, str]:
    """Every known driver name and where it lives (built-ins, then entry points)."""
    table = dict(BUILTIN)
    for point in entry_points(group="warden.drivers"):
        table.setdefault(point.name, point.value)
    return table


def load(name: str) -> Any:
    """The driver class registered under ``name``."""
    table = available()
    if name not in table:
        known = ", ".join(sorted(table))
        raise UnknownDriver(f"unknown driver {name!r}; known drivers: {known}")
    module_name, _, attribute = table[name].partition(":")
    return getattr(importlib.import_module(module_name), attribute)
