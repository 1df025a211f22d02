"""Pure parts of the Dynamixel driver and emulator: units, calibration, settings, CRC, framing."""

from __future__ import annotations

import math
import re

import pytest
from dynamixel_sdk import PacketHandler
from hypothesis import given
from hypothesis import strategies as st

from drivers import registry
from drivers.dynamixel.driver import DynamixelDriver
from drivers.dynamixel.settings import DynamixelSettings
from drivers.dynamixel.tables import STATE_BLOCK_SIZE, STATE_BLOCK_START, hardware_error_names
from drivers.dynamixel.units import (
    RAD_PER_TICK,
    RAD_S_PER_VELOCITY_UNIT,
    JointCalibration,
    le_bytes,
    to_signed,
    to_unsigned,
)
from drivers.settings import SettingsError, settings_from_mapping
from stubs.dynamixel_bus.crc import crc16
from stubs.dynamixel_bus.packet import FrameDecoder, encode, stuff, unstuff

offsets = st.lists(st.floats(-math.pi, math.pi), min_size=6, max_size=6).map(tuple)
directions = st.lists(st.sampled_from((1, -1)), min_size=6, max_size=6).map(tuple)
ticks = st.lists(st.integers(0, 4095), min_size=6, max_size=6).map(tuple)


def calibration(offs: tuple[float, ...], dirs: tuple[int, ...]) -> JointCalibration:
    return JointCalibration(offsets=offs, directions=dirs, current_unit_a=0.00269,
                            torque_per_amp=1.78)


# ---------------------------------------------------------------------------- units


@given(ticks, offsets, directions)
def test_ticks_to_q_and_back_is_exact(raw: tuple[int, ...], offs: tuple[float, ...],
                                      dirs: tuple[int, ...]) -> None:
    cal = calibration(offs, dirs)
    assert cal.ticks_from_q(cal.q_from_ticks(raw)) == raw


@given(st.lists(st.floats(-2.5, 2.5), min_size=6, max_size=6).map(tuple), offsets, directions)
def test_q_to_ticks_and_back_is_within_half_a_tick(q: tuple[float, ...], offs: tuple[float, ...],
                                                   dirs: tuple[int, ...]) -> None:
    cal = calibration(offs, dirs)
    back = cal.q_from_ticks(cal.ticks_from_q(q))
    assert all(abs(a - b) <= RAD_PER_TICK / 2 + 1e-9 for a, b in zip(q, back, strict=True))


def test_centre_tick_is_the_offset_and_direction_flips() -> None:
    cal = calibration((0.5,) * 6, (1, -1, 1, -1, 1, -1))
    q = cal.q_from_ticks((2048 + 1024,) * 6)  # a quarter turn past centre
    assert q[0] == pytest.approx(math.pi / 2 - 0.5)
    assert q[1] == pytest.approx(-(math.pi / 2 - 0.5))
    assert cal.ticks_from_q((-0.5, 0.5, 0, 0, 0, 0))[:2] == (2048, 2048)


@pytest.mark.parametrize(("value", "size", "signed"), [
    (0xFFFFFFFF, 4, -1), (0x80000000, 4, -(2**31)), (0x7FFFFFFF, 4, 2**31 - 1),
    (0xFFFF, 2, -1), (0x8000, 2, -32768), (0x00FF, 2, 255), (0xFE, 1, -2), (5, 4, 5),
])
def test_to_signed_reads_twos_complement(value: int, size: int, signed: int) -> None:
    assert to_signed(value, size) == signed


@given(st.sampled_from((1, 2, 4)).flatmap(
    lambda size: st.tuples(st.just(size), st.integers(-(2 ** (8 * size - 1)),
                                                      2 ** (8 * size - 1) - 1))))
def test_signed_unsigned_round_trip(size_and_value: tuple[int, int]) -> None:
    size, value = size_and_value
    assert to_signed(to_unsigned(value, size), size) == value
    assert int.from_bytes(bytes(le_bytes(value, size)), "little", signed=True) == value


def test_velocity_and_current_units_with_direction() -> None:
    cal = calibration((0.0,) * 6, (1, -1, 1, 1, 1, 1))
    qd = cal.qd_from_units((100, 100, -4, 0, 0, 0))
    assert qd[0] == pytest.approx(100 * 0.229 * 2 * math.pi / 60)
    assert qd[1] == -qd[0] and qd[2] == pytest.approx(-4 * RAD_S_PER_VELOCITY_UNIT)
    effort = cal.effort_from_units((1000, 1000, 0, 0, 0, 0))
    assert effort[0] == pytest.approx(2.69 * 1.78) and effort[1] == -effort[0]


def test_tick_range_in_joint_space_follows_direction() -> None:
    cal = calibration((0.2,) * 6, (1, -1, 1, 1, 1, 1))
    lower, upper = cal.q_range(0, 4095)
    assert lower[0] == pytest.approx(-math.pi - 0.2) and upper[0] < math.pi - 0.2
    assert lower[1] == pytest.approx(-upper[0]) and upper[1] == pytest.approx(-lower[0])


def test_state_block_covers_current_velocity_position() -> None:
    assert (STATE_BLOCK_START, STATE_BLOCK_SIZE) == (126, 10)


def test_hardware_error_names() -> None:
    assert hardware_error_names(0x24) == ["overheating", "overload"]
    assert hardware_error_names(0x42) == ["unknown bits 0x42"]
    assert hardware_error_names(0) == []


# ---------------------------------------------------------------------------- settings


def test_settings_from_manifest_table() -> None:
    table = {"port": "/dev/ttyUSB0", "baud": 4_000_000, "ids": [11, 12, 13],
             "offsets_rad": [0, 0.1, -0.1], "directions": [1, -1, 1]}
    made = settings_from_mapping(DynamixelSettings, table, "drivers.arm")
    assert made.ids == (11, 12, 13) and made.offsets_rad == (0.0, 0.1, -0.1)


@pytest.mark.parametrize(("table", "complaint"), [
    ({"port": "/dev/x", "ids": [1, 2]}, "offsets_rad: 6 values for 2 servo ids"),
    ({"port": "/dev/x", "directions": [1, 1, 1, 1, 1, 0]}, "directions: each must be 1 or -1"),
    ({"port": "/dev/x", "ids": [1, 1, 2, 3, 4, 5]}, "ids: need distinct servo ids"),
    ({"port": "/dev/x", "retries": -1}, "drivers.arm.retries: must be at least 0, got -1"),
    ({"port": "/dev/x", "latency_budget_ms": 0}, "arm.latency_budget_ms: must be positive"),
    ({"port": "/dev/x", "baudrate": 57600}, "drivers.arm.baudrate: unknown key"),
    ({"baud": 57600}, "drivers.arm.port: required key is missing"),
])
def test_bad_settings_name_the_key(table: dict[str, object], complaint: str) -> None:
    with pytest.raises(SettingsError, match=re.escape(complaint)):
        settings_from_mapping(DynamixelSettings, table, "drivers.arm")


def test_registry_and_manifest_table_make_the_driver() -> None:
    driver_class = registry.load("dynamixel")
    assert driver_class is DynamixelDriver
    driver = driver_class.from_mapping({"port": "/dev/ttyUSB0", "baud": 57600}, name="gripper")
    assert driver.name == "gripper" and driver.settings.baud == 57600
    with pytest.raises(SettingsError, match=re.escape("drivers.gripper.bud: unknown key")):
        driver_class.from_mapping({"port": "/dev/ttyUSB0", "bud": 57600}, name="gripper")


# ---------------------------------------------------------------------------- emulator codec


def test_crc_matches_the_e_manual_ping_example() -> None:
    # e-Manual, Protocol 2.0 "Ping" example: FF FF FD 00 01 03 00 01 19 4E
    packet = bytes.fromhex("FFFFFD0001030001")
    assert crc16(packet) == 0x4E19
    assert encode(1, 0x01, b"") == packet + b"\x19\x4e"


@given(st.binary(max_size=200))
def test_crc_agrees_with_the_sdk(data: bytes) -> None:
    assert crc16(data) == PacketHandler(2.0).updateCRC(0, list(data), len(data))


awkward_bytes = st.lists(st.sampled_from([b"\xff", b"\xfd", b"\x00", b"\xff\xff\xfd"]),
                         max_size=60).map(b"".join)


@given(awkward_bytes)
def test_stuffing_round_trip_and_no_header_inside(body: bytes) -> None:
    stuffed = stuff(body)
    assert unstuff(stuffed) == body
    header_at = stuffed.find(b"\xff\xff\xfd")
    while header_at >= 0:
        assert stuffed[header_at + 3:header_at + 4] == b"\xfd"
        header_at = stuffed.find(b"\xff\xff\xfd", header_at + 4)


def test_decoder_resynchronises_after_noise_and_split_reads() -> None:
    packet = encode(3, 0x02, bytes([132, 0, 4, 0]))
    stream = b"\x00\xff\xfd\xff" + packet + packet
    decoder = FrameDecoder()
    frames = [f for chunk in (stream[:9], stream[9:20], stream[20:]) for f in decoder.feed(chunk)]
    assert [(f.servo_id, f.instruction, f.params, f.crc_ok) for f in frames] == [
        (3, 0x02, bytes([132, 0, 4, 0]), True)] * 2


def test_decoder_flags_a_bad_crc() -> None:
    packet = bytearray(encode(3, 0x01, b""))
    packet[-1] ^= 0xFF
    assert [f.crc_ok for f in FrameDecoder().feed(bytes(packet))] == [False]
