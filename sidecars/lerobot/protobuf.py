"""The five protobuf messages of LeRobot's ``AsyncInference`` service, encoded by hand.

Written from the service's descriptor (``lerobot/transport/services_pb2.py`` of LeRobot 0.4.4,
byte-identical in 0.6.1), so the sidecar needs neither protobuf nor LeRobot's generated code:

- ``Empty {}``
- ``PolicySetup { bytes data = 1; }``
- ``Observation { TransferState transfer_state = 1; bytes data = 2; }``
- ``Actions { bytes data = 1; }``
- ``enum TransferState { UNKNOWN = 0; BEGIN = 1; MIDDLE = 2; END = 3; }``

A pickle larger than ``PIECE_BYTES`` goes in pieces, the way LeRobot's ``send_bytes_in_chunks``
sends it: ``BEGIN``, ``MIDDLE``…, ``END``, or a single ``END`` when it fits in one.
"""

from __future__ import annotations

from collections.abc import Iterator
from enum import IntEnum

PIECE_BYTES = 2 * 1024 * 1024
"""LeRobot's CHUNK_SIZE: the most bytes one ``Observation`` message carries."""
MESSAGE_LIMIT = 4 * 1024 * 1024
"""LeRobot's MAX_MESSAGE_SIZE: the largest message either side accepts."""

MOST_FIELDS = 64
"""``Actions`` has one field; a message of millions of tiny unknown ones is refused early."""

_LENGTH_DELIMITED = 2
_VARINT = 0


class TransferState(IntEnum):
    UNKNOWN = 0
    BEGIN = 1
    MIDDLE = 2
    END = 3


class MalformedMessage(ValueError):
    """Bytes that are not the protobuf message they should be."""


EMPTY = b""


def policy_setup(data: bytes) -> bytes:
    return _bytes_field(1, data)


def observation_pieces(data: bytes) -> Iterator[bytes]:
    """The ``Observation`` messages that carry one pickled observation."""
    for start in range(0, max(len(data), 1), PIECE_BYTES):
        if start + PIECE_BYTES >= len(data):
            state = TransferState.END
        elif start == 0:
            state = TransferState.BEGIN
        else:
            state = TransferState.MIDDLE
        yield observation_message(state, data[start:start + PIECE_BYTES])


def observation_message(state: TransferState, piece: bytes) -> bytes:
    return _varint_field(1, state) + _bytes_field(2, piece)


def actions_data(message: bytes) -> bytes:
    """``Actions.data`` (empty when the server answered ``Empty``, as it does on a timeout or
    an inference error). Fields other than 1 are skipped, as protobuf's rules say.

    Raises:
        MalformedMessage: a truncated field, a bad varint or field 1 of another wire type.
    """
    data = b""
    for count, (number, wire_type, value) in enumerate(_fields(message)):
        if count >= MOST_FIELDS:
            raise MalformedMessage(f"more than {MOST_FIELDS} fields in one message")
        if number == 0:
            raise MalformedMessage("field number 0")
        if number == 1:
            if wire_type != _LENGTH_DELIMITED:
                raise MalformedMessage("Actions.data is not length-delimited")
            data = value
    return data


def _fields(message: bytes) -> Iterator[tuple[int, int, bytes]]:
    at = 0
    while at < len(message):
        key, at = _read_varint(message, at)
        number, wire_type = key >> 3, key & 7
        if wire_type == _VARINT:
            _, at = _read_varint(message, at)
            yield number, wire_type, b""
        elif wire_type == _LENGTH_DELIMITED:
            length, at = _read_varint(message, at)
            if at + length > len(message):
                raise MalformedMessage("a field runs past the message's end")
            yield number, wire_type, message[at:at + length]
            at += length
        elif wire_type in (1, 5):  # fixed 64 and fixed 32: skipped by their width
            at += 8 if wire_type == 1 else 4
            if at > len(message):
                raise MalformedMessage("a fixed-width field runs past the message's end")
            yield number, wire_type, b""
        else:
            raise MalformedMessage(f"wire type {wire_type} is not one these messages use")


def _read_varint(message: bytes, at: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if at >= len(message) or shift > 63:
            raise MalformedMessage("a varint is cut or longer than 10 bytes")
        byte = message[at]
        value |= (byte & 0x7F) << shift
        at += 1
        if not byte & 0x80:
            return value, at
        shift += 7


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        low = value & 0x7F
        value >>= 7
        if value:
            out.append(low | 0x80)
        else:
            out.append(low)
            return bytes(out)


def _varint_field(number: int, value: int) -> bytes:
    return _varint(number << 3 | _VARINT) + _varint(value) if value else b""  # proto3: 0 unsent


def _bytes_field(number: int, data: bytes) -> bytes:
    if not data:
        return b""  # proto3 leaves an empty bytes field out
    return _varint(number << 3 | _LENGTH_DELIMITED) + _varint(len(data)) + data
