"""How a manifest's driver table becomes the emulator's command line: the device's build (a
gripper servo, a gripper drive, the UR gripper's wiring) follows the manifest, and a wiring the
emulator cannot build is refused naming the key, before any process starts."""

from __future__ import annotations

import dataclasses
from typing import Any

import msgspec
import pytest

from kernel.manifest import Manifest, ManifestError
from stubs.cell.emulated import LAUNCHERS
from tests.cell.harness import manifest


def _with_driver(name: str, **settings: Any) -> Manifest:
    loaded = manifest(name)
    return dataclasses.replace(
        loaded, driver_settings=msgspec.structs.replace(loaded.driver_settings, **settings))


def _args(loaded: Manifest) -> tuple[str, ...]:
    return LAUNCHERS[loaded.driver_name](loaded, "mujoco").args


def test_the_shipped_manifests_give_every_emulator_its_gripper() -> None:
    dynamixel = _args(manifest("sim-dynamixel.toml"))
    assert dynamixel[dynamixel.index("--gripper-id") + 1] == "7"
    canopen = _args(manifest("sim-canopen.toml"))
    assert canopen[canopen.index("--gripper-node") + 1] == "7"
    ur = _args(manifest("sim-ur5e-rtde.toml"))
    assert ur[ur.index("--gripper-output") + 1] == "0"
    assert ur[ur.index("--gripper-feedback-input") + 1] == "0"


def test_the_ur_gripper_wiring_reaches_the_emulator() -> None:
    args = _args(_with_driver("sim-ur5e-rtde.toml", gripper_output=1,
                              gripper_feedback="standard_analog_input1"))
    assert args[args.index("--gripper-output") + 1] == "1"
    assert args[args.index("--gripper-feedback-input") + 1] == "1"


def test_no_gripper_no_flags() -> None:
    loaded = manifest("sim-ur5e-rtde.toml")
    settings = msgspec.structs.replace(loaded.driver_settings, gripper_output=None)
    assert not any(a.startswith("--gripper") for a in _args(
        dataclasses.replace(loaded, driver_settings=settings)))


@pytest.mark.parametrize(("key", "value"), [("gripper_feedback_open", 5.0),
                                            ("gripper_feedback_closed", 1.0),
                                            ("gripper_max_opening_m", 0.14)])
def test_a_ur_gripper_signal_the_emulator_cannot_build_names_the_key(
        key: str, value: float) -> None:
    with pytest.raises(ManifestError, match=rf"driver\.{key}: the emulated controller's"):
        _args(_with_driver("sim-ur5e-rtde.toml", **{key: value}))
