"""The UR status-word mapping and the stall watchdog, as plain functions (no emulator)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from assurance.reasons import ReasonCode
from drivers.ur_rtde import tables
from drivers.ur_rtde.link import Link, LinkStalled
from drivers.ur_rtde.settings import URSettings
from drivers.ur_rtde.tables import RobotMode, RuntimeState, SafetyBit, device_faults

E_STOP_MASK = sum(1 << bit for bit in tables.E_STOP_BITS)
STOP_MASK = sum(1 << bit for bit in tables.SAFETY_STOP_BITS)


@given(bits=st.integers(0, (1 << 11) - 1), mode=st.integers(-1, 8), runtime=st.integers(0, 5),
       streaming=st.booleans())
def test_every_status_word_maps_to_the_right_reason_most_severe_first(
    bits: int, mode: int, runtime: int, streaming: bool,
) -> None:
    faults = device_faults(bits, mode, runtime, streaming)
    reasons = [fault.reason for fault in faults]
    if bits & E_STOP_MASK:
        assert reasons[0] is ReasonCode.E_STOP
    elif bits & STOP_MASK:
        assert reasons[0] is ReasonCode.CONTROLLER_FAULT
    unhealthy_stream = streaming and (mode != RobotMode.RUNNING
                                      or runtime != RuntimeState.PLAYING)
    assert bool(faults) == bool(bits & (E_STOP_MASK | STOP_MASK) or unhealthy_stream)
    assert set(reasons) <= {ReasonCode.E_STOP, ReasonCode.CONTROLLER_FAULT}


def test_fault_details_name_the_bits() -> None:
    [fault] = device_faults(1 << SafetyBit.PROTECTIVE_STOP, RobotMode.RUNNING,
                            RuntimeState.STOPPED, streaming=False)
    assert fault.detail == "safety stop: PROTECTIVE_STOP"
    streaming = device_faults(1, RobotMode.POWER_OFF, 7, streaming=True)
    assert [f.detail for f in streaming] == [
        "robot mode POWER_OFF", "control script not running (runtime state 7)"]


def test_reduced_mode_is_not_a_fault() -> None:
    bits = 1 << SafetyBit.NORMAL | 1 << SafetyBit.REDUCED
    assert device_faults(bits, RobotMode.RUNNING, RuntimeState.PLAYING, streaming=True) == []


def test_supported_versions() -> None:
    assert tables.version_supported((5, 11, 1, 108318))
    assert tables.version_supported((5, 4, 0, 0))
    assert not tables.version_supported((5, 3, 9, 0))
    assert not tables.version_supported((3, 15, 7, 0))
    assert not tables.version_supported((10, 7, 0, 0))


def test_the_watchdog_fires_after_stall_periods_without_a_new_timestamp() -> None:
    link = Link("ur5e", URSettings(host="10.0.0.7", stall_periods=10))  # 20 ms at 500 Hz
    link._track_freshness(1.000, 0)
    link._track_freshness(1.000, 15_000_000)  # repeated sample, 15 ms: still within bounds
    link._track_freshness(1.002, 19_000_000)  # new sample resets the clock
    link._track_freshness(1.002, 38_000_000)
    with pytest.raises(LinkStalled, match=r"no new RTDE data for 0\.021 s"):
        link._track_freshness(1.002, 40_000_000)
