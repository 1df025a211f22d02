"""Gripper settings of the CiA 402 driver, its units, and the emulator's matching flags."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.base import DriverInitError
from drivers.canopen402.bringup import check_bus_load
from drivers.canopen402.settings import CiA402Settings
from drivers.canopen402.units import GRIPPER_COUNTS_PER_M, GripperScale
from drivers.settings import SettingsError
from stubs.cia402_drive.__main__ import parse_args
from stubs.cia402_drive.encoders import LinearEncoder
from tests.drivers.cia402_testbed import emulator_config

TABLE = {"interface": "socketcan", "channel": "can0", "node_ids": [1, 2],
         "counts_per_rev": [4096, 4096]}


def test_gripper_settings_from_a_manifest_table() -> None:
    settings = CiA402Settings.from_mapping({**TABLE, "gripper_node": 7,
                                            "gripper_counts_per_m": 2_000_000})
    assert settings.gripper_node == 7
    assert settings.gripper_counts_per_m == 2e6
    assert settings.drive_ids == (1, 2, 7)  # joints in order, then the gripper
    assert settings.node_label(7) == "node 7 (gripper)" and settings.node_label(2) == "node 2"


def test_no_gripper_by_default_and_a_micrometre_per_count() -> None:
    settings = CiA402Settings.from_mapping(TABLE)
    assert settings.gripper_node is None
    assert settings.drive_ids == (1, 2)
    assert settings.gripper_counts_per_m == GRIPPER_COUNTS_PER_M == 1e6


@pytest.mark.parametrize(("change", "message"), [
    ({"gripper_node": 0}, "canopen402.gripper_node: must be at least 1, got 0"),
    ({"gripper_node": 128}, "canopen402.gripper_node: must be at most 127, got 128"),
    ({"gripper_node": 2}, "gripper_node 2 is also in node_ids"),
    ({"gripper_node": "7"}, "canopen402.gripper_node:"),
    ({"gripper_node": True}, "canopen402.gripper_node:"),
    ({"gripper_node": 7.0}, "canopen402.gripper_node:"),
    ({"gripper_counts_per_m": 0}, "canopen402.gripper_counts_per_m: must be positive, got 0"),
    ({"gripper_counts_per_m": -1e6}, "canopen402.gripper_counts_per_m: must be positive"),
    ({"gripper_counts_per_m": float("nan")}, "canopen402.gripper_counts_per_m: must be a finite"),
    ({"gripper_counts_per_m": float("inf")}, "canopen402.gripper_counts_per_m: must be a finite"),
    ({"gripper_counts_per_m": "1e6"}, "canopen402.gripper_counts_per_m:"),
    ({"gripper_counts_per_m": 1e12}, "stroke outside the drive's INTEGER32 position range"),
    ({"gripper_id": 7}, "canopen402.gripper_id: unknown key"),
])
def test_bad_gripper_settings_name_the_key(change: dict[str, object], message: str) -> None:
    with pytest.raises(SettingsError, match=message):
        CiA402Settings.from_mapping({**TABLE, **change})


def test_the_gripper_counts_in_the_bus_load() -> None:
    """Six joint drives fill 90 % of a 1 Mbit/s bus at 400 Hz; the gripper's PDOs tip it over."""
    joints = {**TABLE, "node_ids": [1, 2, 3, 4, 5, 6], "counts_per_rev": [4096] * 6}
    check_bus_load(CiA402Settings.from_mapping(joints), 1 / 400)
    with pytest.raises(DriverInitError, match=r"^canopen402: 7 drives at 400 Hz"):
        check_bus_load(CiA402Settings.from_mapping({**joints, "gripper_node": 7}), 1 / 400)


opening = st.floats(min_value=0.0, max_value=0.2, allow_nan=False)
resolution = st.floats(min_value=1e3, max_value=1e8, allow_nan=False)


@given(resolution, opening)
def test_driver_and_emulator_agree_on_gripper_counts(counts_per_m: float, x: float) -> None:
    scale, encoder = GripperScale(counts_per_m), LinearEncoder(counts_per_m)
    assert scale.to_counts(x) == encoder.counts(x)
    assert abs(scale.to_m(scale.to_counts(x)) - x) <= 0.5 / counts_per_m + 1e-15
    assert scale.to_m(12345) == pytest.approx(encoder.position(12345))


def test_gripper_opening_beyond_int32_is_a_value_error() -> None:
    with pytest.raises(ValueError, match="INTEGER32"):
        GripperScale(1e12).to_counts(0.085)


def test_emulator_flags_default_to_the_driver_default() -> None:
    args = parse_args(["--channel", "239.1.2.3", "--gripper-node", "7"])
    assert (args.gripper_node, args.gripper_counts_per_m) == (7, GRIPPER_COUNTS_PER_M)
    assert parse_args(["--channel", "239.1.2.3"]).gripper_node is None
    custom = parse_args(["--channel", "x", "--gripper-node", "9", "--gripper-counts-per-m", "5e5"])
    assert (custom.gripper_node, custom.gripper_counts_per_m) == (9, 5e5)


def test_emulator_refuses_a_gripper_node_shared_with_a_joint() -> None:
    with pytest.raises(ValueError, match="gripper node 3"):
        emulator_config("virtual", "x", gripper_node=3)
