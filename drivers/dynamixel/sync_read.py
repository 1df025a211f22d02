"""GroupSyncRead that keeps what the SDK throws away: each servo's error byte, and who failed.

dynamixel_sdk 4.1.0's ``GroupSyncRead.rxPacket`` and ``fastSyncReadRxPacket`` discard the
status packet's error byte, which carries the hardware-error alert bit (0x80), and do not say
which servo failed to answer. Those are exactly what a driver needs to name a faulted or silent
servo without an extra round trip per cycle, so the two receive methods are redone here on top
of the same PacketHandler calls the SDK uses. Everything else (parameters, getData) is the SDK's.
"""

from __future__ import annotations

from dynamixel_sdk import BROADCAST_ID, COMM_RX_CORRUPT, COMM_SUCCESS, GroupSyncRead

ERROR_ID_CRC = 4
"""Bytes a fast sync read reply adds around each servo's data: error, id, and a CRC-16."""


class StatusSyncRead(GroupSyncRead):  # type: ignore[misc]  # the SDK is untyped
    def __init__(self, port: object, handler: object, start_address: int, data_length: int):
        super().__init__(port, handler, start_address, data_length)
        self.errors: dict[int, int] = {}
        self.failed_id: int | None = None

    def rxPacket(self) -> int:  # SDK method name
        self._reset()
        result = COMM_SUCCESS
        for dxl_id in self.data_dict:
            data, result, error = self.ph.readRx(self.port, dxl_id, self.data_length)
            if result != COMM_SUCCESS:
                self.failed_id = dxl_id  # replies come in id order: this one broke the chain
                return int(result)
            self.data_dict[dxl_id] = data
            self.errors[dxl_id] = error
        self.last_result = True
        return COMM_SUCCESS

    def fastSyncReadRxPacket(self) -> int:  # SDK method name
        self._reset()
        count = len(self.data_dict)
        stride = self.data_length + ERROR_ID_CRC
        raw, result, _ = self.ph.fastSyncReadRx(self.port, BROADCAST_ID, stride * count)
        if result != COMM_SUCCESS:
            return int(result)
        if len(raw) < stride * count:
            return COMM_RX_CORRUPT
        for index in range(count):
            start = index * stride
            error, dxl_id = raw[start], raw[start + 1]
            if dxl_id not in self.data_dict:
                return COMM_RX_CORRUPT
            self.data_dict[dxl_id] = bytearray(raw[start + 2:start + 2 + self.data_length])
            self.errors[dxl_id] = error
        self.last_result = True
        return COMM_SUCCESS

    def _reset(self) -> None:
        self.last_result = False
        self.errors = {}
        self.failed_id = None
