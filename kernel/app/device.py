"""What a cell runs against: a *world* that owns the driver and, in simulation, the physics.

A real device is a :class:`DeviceWorld`: the manifest's driver, from the driver registry,
nothing else (no ground truth, no parts feeder). Simulated worlds (the in-process plant, an
emulator process with the plant behind it) are stand-ins in ``stubs/`` reached through
:mod:`kernel.app.standins`.
"""

from __future__ import annotations

import math
from typing import Any, Protocol

from drivers import registry
from drivers.base import Driver, DriverInitError
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


def driver_from_manifest(manifest: Manifest, settings: Any = None) -> Driver:
    """The manifest's driver, built through the registry from its decoded settings (or from
    ``settings``, the same type with the address an emulator gave filled in).

    Raises:
        ManifestError: an unknown driver, or one the registry cannot build from settings.
    """
    where = f"{manifest.path}: driver"
    try:
        driver = registry.load(manifest.driver_name)
        return driver.from_settings(
            manifest.driver_settings if settings is None else settings, manifest.driver_name)
    except registry.UnknownDriver as error:
        raise ManifestError(f"{where}.name: {error}") from None
    except DriverInitError as error:
        raise ManifestError(f"{where}: {error}") from None


class DeviceWorld:
    """A real device: the driver only. Nothing here can see ground truth or feed parts."""

    has_ground_truth = False

    def __init__(self, manifest: Manifest) -> None:
        self._driver = driver_from_manifest(manifest)

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
