"""The registry's table of built-in settings types agrees with the drivers' own declarations,
so reading ``[driver]`` without loading a driver (as the safety monitor does) decodes exactly
what the driver will be built from."""

from __future__ import annotations

import pytest

from drivers import registry


@pytest.mark.parametrize("name", sorted(registry.BUILTIN_SETTINGS))
def test_a_builtin_drivers_settings_are_the_ones_it_declares(name: str) -> None:
    driver = registry.load(name)
    settings_type, address_keys = registry.declared_settings(name)
    assert settings_type is driver.settings_type
    assert dict(address_keys) == dict(driver.address_keys)
