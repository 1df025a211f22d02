"""What a cell runs against: a *world* that owns the driver and, in simulation, the physics.

A real device is a :class:`DeviceWorld`: the manifest's driver, from the driver registry,
nothing else (no ground truth, no parts feeder). Simulated worlds (the in-process plant, an
emulator process with the plant behind it) are stand-ins in ``stubs/`` reached through
:mod:`kernel.app.standins`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Protocol

from drivers import registry
from drivers.base import Driver
from drivers.settings import SettingsError
from kernel.manifest import Manifest, ManifestError


class World(Protocol):
    has_ground_truth: bool
    """A simulator that knows the true state of the parts (an extra check for VERIFY)."""

    def driver(self) -> Driver: ...

    def advance(self) -> None:
        """One control period of physics has passed (no-op where the device steps itself)."""
        ...

    def insertion_depth(self) -> float:
        """The simulator's true insertion depth, metres (NaN where nobody can see it)."""
        ...

    def feed_part(self) -> None:
        """The feeder presents a new part for the next cycle."""
        ...

    def close(self) -> None: ...


def driver_from_manifest(manifest: Manifest, table: Mapping[str, Any]) -> Driver:
    """The manifest's driver, built through the registry; bad settings name the key.

    Raises:
        ManifestError: an unknown driver, or settings that do not fit it.
    """
    where = f"{manifest.path}: driver"
    try:
        return registry.load(manifest.driver_name).from_mapping(
            table, where, name=manifest.driver_name)
    except registry.UnknownDriver as error:
        raise ManifestError(f"{where}.name: {error}") from None
    except (SettingsError, ValueError) as error:
        raise ManifestError(str(error)) from None


class DeviceWorld:
    """A real device: the driver only. Nothing here can see ground truth or feed parts."""

    has_ground_truth = False

    def __init__(self, manifest: Manifest) -> None:
        self._driver = driver_from_manifest(manifest, manifest.driver_settings)

    def driver(self) -> Driver:
        return self._driver

    def advance(self) -> None:
        """The device moves in real time on its own."""

    def insertion_depth(self) -> float:
        return math.nan  # only the measured evidence can tell on a real cell

    def feed_part(self) -> None:
        """Parts are presented by the real cell."""

    def close(self) -> None:
        """The driver's aclose releases the device."""
