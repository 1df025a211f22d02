"""The parts of dynamixel_sdk 4.1.0 this driver uses, typed (the SDK ships no annotations).

Every SDK call returns plain ints: ``COMM_*`` results (negative on failure) and the status
packet's error byte (``ERRBIT_ALERT`` plus a 7-bit error number). None of it is thread-safe:
one port is used from one thread only (see :class:`drivers.device_thread.DeviceThread`).
"""

from __future__ import annotations

from typing import Protocol

from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupSyncWrite,
    PacketHandler,
)

__all__ = [
    "COMM_RX_CORRUPT",
    "COMM_RX_TIMEOUT",
    "COMM_SUCCESS",
    "RETRYABLE",
    "SDK_BAUD_RATES",
    "GroupSyncReadLike",
    "GroupSyncWriteLike",
    "PacketHandlerLike",
    "PortHandlerLike",
    "make_packet_handler",
    "make_sync_write",
]

RETRYABLE = frozenset({COMM_RX_TIMEOUT, COMM_RX_CORRUPT})
"""Results worth another attempt: a late or garbled reply, not a closed port."""

SDK_BAUD_RATES = (
    9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600, 1_000_000,
    1_152_000, 2_000_000, 2_500_000, 3_000_000, 3_500_000, 4_000_000,
)
"""For messages only: PortHandler.getCFlagBaud is the authority (it refuses anything else)."""


class PortHandlerLike(Protocol):
    is_open: bool

    def openPort(self) -> bool: ...

    def closePort(self) -> None: ...

    def setBaudRate(self, baudrate: int) -> bool: ...

    def getCFlagBaud(self, baudrate: int) -> int: ...

    def getPortName(self) -> str: ...


class PacketHandlerLike(Protocol):
    def ping(self, port: PortHandlerLike, dxl_id: int) -> tuple[int, int, int]: ...

    def read1ByteTxRx(
        self, port: PortHandlerLike, dxl_id: int, address: int
    ) -> tuple[int, int, int]: ...

    def read2ByteTxRx(
        self, port: PortHandlerLike, dxl_id: int, address: int
    ) -> tuple[int, int, int]: ...

    def read4ByteTxRx(
        self, port: PortHandlerLike, dxl_id: int, address: int
    ) -> tuple[int, int, int]: ...

    def write1ByteTxRx(
        self, port: PortHandlerLike, dxl_id: int, address: int, data: int
    ) -> tuple[int, int]: ...

    def getTxRxResult(self, result: int) -> str: ...

    def getRxPacketError(self, error: int) -> str: ...


class GroupSyncWriteLike(Protocol):
    def addParam(self, dxl_id: int, data: list[int]) -> bool: ...

    def changeParam(self, dxl_id: int, data: list[int]) -> bool: ...

    def txPacket(self) -> int: ...


class GroupSyncReadLike(Protocol):
    errors: dict[int, int]
    failed_id: int | None

    def addParam(self, dxl_id: int) -> bool: ...

    def fastSyncRead(self) -> int: ...

    def txRxPacket(self) -> int: ...

    def getData(self, dxl_id: int, address: int, data_length: int) -> int: ...


def make_packet_handler() -> PacketHandlerLike:
    handler: PacketHandlerLike = PacketHandler(2.0)
    return handler


def make_sync_write(
    port: PortHandlerLike, handler: PacketHandlerLike, address: int, size: int
) -> GroupSyncWriteLike:
    group: GroupSyncWriteLike = GroupSyncWrite(port, handler, address, size)
    return group
