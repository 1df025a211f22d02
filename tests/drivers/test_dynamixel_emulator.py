"""The bus emulator seen through the bare dynamixel_sdk: what a real X-series bus would answer.

These pin down the emulator's wire behaviour independently of the driver, so a driver test that
passes cannot be passing only because driver and emulator share the same mistake.
"""

from __future__ import annotations

import importlib.util
import time
from collections.abc import Iterator

import pytest
from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

from stubs.dynamixel_bus.launch import BusEmulator

IDS = (1, 2, 3, 4, 5, 6)
ALERT = 0x80
ACCESS_ERROR, DATA_LIMIT_ERROR, RESULT_FAIL = 7, 6, 1


@pytest.fixture(scope="module")
def bus() -> Iterator[BusEmulator]:
    with BusEmulator("--ids", "1,2,3,4,5,6", "--model", "1060") as emulator:
        yield emulator


@pytest.fixture
def sdk(bus: BusEmulator) -> Iterator[tuple[PortHandler, PacketHandler]]:
    port = PortHandler(bus.port)
    port.openPort()
    try:
        yield port, PacketHandler(2.0)
    finally:
        port.closePort()
        bus.inject("clear")


def state_reader(port: PortHandler, sdk: PacketHandler) -> GroupSyncRead:
    reader = GroupSyncRead(port, sdk, 126, 10)
    for dxl_id in IDS:
        reader.addParam(dxl_id)
    return reader


def test_ping_answers_model_and_unknown_id_times_out(
    sdk: tuple[PortHandler, PacketHandler],
) -> None:
    port, handler = sdk
    assert handler.ping(port, 4) == (1060, COMM_SUCCESS, 0)
    assert handler.ping(port, 9)[1] == COMM_RX_TIMEOUT


def test_broadcast_ping_finds_every_servo(sdk: tuple[PortHandler, PacketHandler]) -> None:
    port, handler = sdk
    found, result = handler.broadcastPing(port)  # the SDK always waits ~0.8 s here
    assert result == COMM_SUCCESS and sorted(found) == list(IDS)


def test_byte_stuffing_both_ways(sdk: tuple[PortHandler, PacketHandler]) -> None:
    port, handler = sdk
    awkward = 0x00FDFFFF  # little-endian FF FF FD 00: a header inside the payload
    assert handler.write4ByteTxRx(port, 2, 112, awkward) == (COMM_SUCCESS, 0)
    assert handler.read4ByteTxRx(port, 2, 112) == (awkward, COMM_SUCCESS, 0)


def test_eeprom_is_locked_while_torque_is_on(sdk: tuple[PortHandler, PacketHandler]) -> None:
    port, handler = sdk
    assert handler.write1ByteTxRx(port, 1, 11, 3) == (COMM_SUCCESS, 0)
    assert handler.write1ByteTxRx(port, 1, 64, 1) == (COMM_SUCCESS, 0)
    assert handler.write1ByteTxRx(port, 1, 11, 3) == (COMM_SUCCESS, ACCESS_ERROR)
    assert handler.write1ByteTxRx(port, 1, 132, 0) == (COMM_SUCCESS, ACCESS_ERROR)  # read-only


def test_goal_outside_position_limits_is_refused(sdk: tuple[PortHandler, PacketHandler]) -> None:
    port, handler = sdk
    assert handler.write4ByteTxRx(port, 3, 116, 5000) == (COMM_SUCCESS, DATA_LIMIT_ERROR)


def test_sync_write_moves_the_plant(sdk: tuple[PortHandler, PacketHandler]) -> None:
    port, handler = sdk
    start = handler.read4ByteTxRx(port, 6, 132)[0]
    goals = GroupSyncWrite(port, handler, 116, 4)
    goals.addParam(6, list((start + 300).to_bytes(4, "little")))
    assert handler.write1ByteTxRx(port, 6, 64, 1) == (COMM_SUCCESS, 0)
    assert goals.txPacket() == COMM_SUCCESS
    time.sleep(0.3)
    assert abs(handler.read4ByteTxRx(port, 6, 132)[0] - (start + 300)) <= 2


def test_hardware_error_sets_alert_and_switches_torque_off(
    bus: BusEmulator, sdk: tuple[PortHandler, PacketHandler]
) -> None:
    port, handler = sdk
    assert handler.write1ByteTxRx(port, 2, 64, 1) == (COMM_SUCCESS, 0)
    bus.inject("hardware_error", id=2, bit="overload")
    assert handler.read1ByteTxRx(port, 2, 70) == (0x20, COMM_SUCCESS, ALERT)
    assert handler.read1ByteTxRx(port, 2, 64) == (0, COMM_SUCCESS, ALERT)
    assert handler.write1ByteTxRx(port, 2, 64, 1) == (COMM_SUCCESS, ALERT | RESULT_FAIL)
    assert handler.ping(port, 3) == (1060, COMM_SUCCESS, 0)  # only servo 2 alerts


def test_fast_and_plain_sync_read_agree(sdk: tuple[PortHandler, PacketHandler]) -> None:
    port, handler = sdk
    reader = state_reader(port, handler)
    assert reader.fastSyncRead() == COMM_SUCCESS
    fast = [reader.getData(i, 132, 4) for i in IDS]
    assert reader.txRxPacket() == COMM_SUCCESS
    assert [reader.getData(i, 132, 4) for i in IDS] == fast
    assert fast == [handler.read4ByteTxRx(port, i, 132)[0] for i in IDS]


def test_silent_servo_breaks_the_reply_chain(
    bus: BusEmulator, sdk: tuple[PortHandler, PacketHandler]
) -> None:
    port, handler = sdk
    reader = state_reader(port, handler)
    bus.inject("silent", id=4)
    assert reader.fastSyncRead() == COMM_RX_CORRUPT  # servos 1-3 answered, then nothing
    assert reader.txRxPacket() == COMM_RX_TIMEOUT
    bus.inject("silent", id=1)
    assert reader.fastSyncRead() == COMM_RX_TIMEOUT  # nobody started the chain
    assert handler.ping(port, 2)[1] == COMM_SUCCESS


def test_crc_fault_corrupts_the_next_replies_only(
    bus: BusEmulator, sdk: tuple[PortHandler, PacketHandler]
) -> None:
    port, handler = sdk
    bus.inject("crc", count=2)
    assert handler.ping(port, 1)[1] == COMM_RX_CORRUPT
    assert state_reader(port, handler).fastSyncRead() == COMM_RX_CORRUPT
    assert handler.ping(port, 1)[1] == COMM_SUCCESS


def test_wrong_line_rate_gets_no_answer(bus: BusEmulator) -> None:
    port = PortHandler(bus.port)
    port.setBaudRate(57_600)
    try:
        assert PacketHandler(2.0).ping(port, 1)[1] == COMM_RX_TIMEOUT
        port.setBaudRate(1_000_000)
        assert PacketHandler(2.0).ping(port, 1)[1] == COMM_SUCCESS
    finally:
        port.closePort()


def test_unknown_fault_is_refused(bus: BusEmulator) -> None:
    with pytest.raises(RuntimeError, match="no servo with id 42"):
        bus.inject("silent", id=42)


def test_mujoco_plant_behind_the_bus() -> None:
    if importlib.util.find_spec("stubs.plant.mujoco_plant") is None:
        pytest.skip("stubs/plant/mujoco_plant.py (MujocoPlant) does not exist yet")
    with BusEmulator("--ids", "1,2,3,4,5,6", "--plant", "mujoco") as mujoco_bus:
        port = PortHandler(mujoco_bus.port)
        port.openPort()
        try:
            handler = PacketHandler(2.0)
            start = handler.read4ByteTxRx(port, 1, 132)[0]
            assert handler.write4ByteTxRx(port, 1, 116, start + 200) == (COMM_SUCCESS, 0)
            assert handler.write1ByteTxRx(port, 1, 64, 1) == (COMM_SUCCESS, 0)
            time.sleep(0.5)
            reader = state_reader(port, handler)
            assert reader.fastSyncRead() == COMM_SUCCESS
            reached = reader.getData(1, 132, 4)
        finally:
            port.closePort()
    assert abs(reached - (start + 200)) <= 10  # physics: the base joint tracks within ~15 mrad
