"""The UR gripper's settings and wiring, without a controller: what a manifest may say, and
how a commanded opening becomes an output level and a feedback signal becomes metres."""

from __future__ import annotations

import math

import pytest

from drivers.settings import SettingsError
from drivers.ur_rtde.driver import URRTDEDriver
from drivers.ur_rtde.gripper import GripperWiring
from drivers.ur_rtde.settings import URSettings

HOST = "10.0.0.7"


def wiring(**settings: object) -> GripperWiring:
    found = GripperWiring.from_settings(URSettings(host=HOST, gripper_output=0, **settings))
    assert found is not None
    return found


def test_no_gripper_by_default() -> None:
    assert URSettings(host=HOST).gripper_output is None
    assert GripperWiring.from_settings(URSettings(host=HOST)) is None


def test_manifest_table_with_a_gripper() -> None:
    table = {"host": HOST, "gripper_output": 1, "gripper_feedback": "standard_analog_input1",
             "gripper_feedback_closed": 4, "gripper_feedback_open": 20}
    settings = URSettings.from_mapping(table, "arm.driver")
    assert (settings.gripper_output, settings.gripper_feedback) == (1, "standard_analog_input1")
    assert settings.gripper_feedback_closed == 4.0  # integers are taken as readings too


@pytest.mark.parametrize(("key", "value", "message"), [
    ("gripper_output", 2, r"gripper_output = 2 is not a tool digital output"),
    ("gripper_output", -1, r"gripper_output = -1"),
    ("gripper_output", True, r"arm\.driver\.gripper_output: .*True"),
    ("gripper_output", "0", r"arm\.driver\.gripper_output"),
    ("gripper_feedback", "tool_analog_input0", r"gripper_feedback.*cannot read the tool analog"),
    ("gripper_feedback", "standard_analog_input2", r"gripper_feedback = 'standard_analog_inp"),
    ("gripper_feedback_closed", 10.0, r"gripper_feedback_closed = 10\.0 and gripper_feedbac"),
    ("gripper_feedback_open", math.inf, r"driver\.gripper_feedback_open: must be a finite"),
    ("gripper_max_opening_m", 0.0, r"driver\.gripper_max_opening_m: must be positive, got 0\.0"),
    ("gripper_max_opening_m", math.nan, r"gripper_max_opening_m: must be a finite number.*nan"),
    ("gripper_speed", 1.0, r"arm\.driver\.gripper_speed: unknown key"),
])
def test_bad_gripper_settings_are_refused_naming_the_key(key: str, value: object,
                                                         message: str) -> None:
    table = {"host": HOST, "gripper_output": 0, key: value}
    with pytest.raises(SettingsError, match=message):
        URSettings.from_mapping(table, "arm.driver")
    with pytest.raises(SettingsError, match=message):
        URRTDEDriver.from_mapping(table, "arm.driver", name="ur5e")


def test_feedback_is_checked_even_without_a_gripper() -> None:
    """A typo is refused even before the gripper is switched on."""
    with pytest.raises(SettingsError, match="gripper_feedback"):
        URSettings.from_mapping({"host": HOST, "gripper_feedback": "analog0"}, "arm.driver")


def test_a_binary_gripper_closes_below_half_the_maximum_opening() -> None:
    grip = wiring()
    assert grip.closes(0.0) and grip.closes(0.0424)
    assert not grip.closes(0.0425) and not grip.closes(0.085)
    assert not grip.closes(1.0)  # more than fully open: open
    assert wiring(gripper_max_opening_m=0.14).closes(0.0699)


def test_feedback_volts_scale_to_metres_and_clamp() -> None:
    grip = wiring()
    assert grip.opening_m(0.0) == 0.0
    assert grip.opening_m(5.0) == pytest.approx(0.0425)
    assert grip.opening_m(10.0) == pytest.approx(0.085)
    assert grip.opening_m(10.3) == pytest.approx(0.085)  # sensor noise past the end
    assert grip.opening_m(-0.2) == 0.0


def test_current_loop_and_inverted_feedback() -> None:
    four_to_twenty = wiring(gripper_feedback_closed=0.004, gripper_feedback_open=0.020)
    assert four_to_twenty.opening_m(0.012) == pytest.approx(0.0425)
    inverted = wiring(gripper_feedback_closed=10.0, gripper_feedback_open=0.0)
    assert inverted.opening_m(10.0) == 0.0
    assert inverted.opening_m(2.5) == pytest.approx(0.06375)
    assert wiring(gripper_feedback="standard_analog_input1").getter == "getStandardAnalogInput1"
