"""Protocol 2.0 framing: header FF FF FD 00, byte stuffing, CRC-16, and a streaming decoder.

Frame: ``FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAMS... | CRC_L CRC_H`` where LEN counts
INST, PARAMS and CRC. Inside INST..PARAMS every ``FF FF FD`` is sent as ``FF FF FD FD`` so that a
header never appears in the middle of a packet; the CRC covers the stuffed bytes.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from enum import IntEnum

from stubs.dynamixel_bus.crc import crc16

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
MAX_PACKET_LENGTH = 1024
"""Longest LEN the SDK accepts (RXPACKET_MAX_LEN); anything longer is line noise."""
ALERT = 0x80
"""Error-byte bit: the servo has a hardware error (see Hardware Error Status, address 70)."""


class Instruction(IntEnum):
    """The instructions the emulated bus answers; any other gets an instruction error."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A


class ErrorCode(IntEnum):
    """The low 7 bits of a status packet's error byte."""

    NONE = 0
    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


@dataclass(frozen=True, slots=True)
class Frame:
    """One instruction packet as received, parameters already unstuffed."""

    servo_id: int
    instruction: int
    params: bytes
    crc_ok: bool


def stuff(body: bytes) -> bytes:
    """Insert FD after every FF FF FD in ``body`` (instruction and parameters)."""
    out = bytearray()
    for byte in body:
        out.append(byte)
        if byte == 0xFD and out[-3:-1] == b"\xff\xff":
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Drop the FD that :func:`stuff` inserted after each FF FF FD."""
    out = bytearray()
    index = 0
    while index < len(body):
        out.append(body[index])
        if body[index] == 0xFD and out[-3:-1] == b"\xff\xff" and body[index + 1:index + 2] == (
            b"\xfd"
        ):
            index += 1  # skip the stuffing byte
        index += 1
    return bytes(out)


def encode(servo_id: int, instruction: int, params: bytes, *, stuffed: bool = True) -> bytes:
    """A complete packet with header, length and CRC.

    ``stuffed=False`` is for fast sync read replies: dynamixel_sdk 4.1.0 does not remove stuffing
    from them (``rxPacket(port, fast_option=True)``), so a stuffed reply would shift the data.
    """
    body = bytes([instruction]) + params
    if stuffed:
        body = stuff(body)
    head = HEADER + bytes([servo_id]) + (len(body) + 2).to_bytes(2, "little")
    frame = head + body
    return frame + crc16(frame).to_bytes(2, "little")


def encode_status(servo_id: int, error: int, params: bytes = b"") -> bytes:
    return encode(servo_id, Instruction.STATUS, bytes([error]) + params)


class FrameDecoder:
    """Turns a byte stream into :class:`Frame`s, resynchronising on the header after noise."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def feed(self, data: bytes) -> Iterator[Frame]:
        self._buffer += data
        while True:
            frame = self._next_frame()
            if frame is None:
                return
            yield frame

    def _next_frame(self) -> Frame | None:
        start = self._buffer.find(HEADER)
        if start < 0:
            del self._buffer[: max(0, len(self._buffer) - 3)]  # keep a possible partial header
            return None
        del self._buffer[:start]
        if len(self._buffer) < 7:
            return None
        length = int.from_bytes(self._buffer[5:7], "little")
        if not 3 <= length <= MAX_PACKET_LENGTH:
            del self._buffer[0]  # not a real header; look for the next one
            return self._next_frame()
        if len(self._buffer) < 7 + length:
            return None
        raw = bytes(self._buffer[: 7 + length])
        del self._buffer[: 7 + length]
        return _parse(raw)


def _parse(raw: bytes) -> Frame:
    crc_ok = crc16(raw[:-2]) == int.from_bytes(raw[-2:], "little")
    body = unstuff(raw[7:-2])
    return Frame(servo_id=raw[4], instruction=body[0], params=body[1:], crc_ok=crc_ok)
