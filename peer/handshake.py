"""The server's side of the compatibility handshake, written from ``docs/protocol.md``.

The client states its side (:class:`ClientHello`), the server offers its own
(:class:`HandshakeOffer`) and the client's core decides (:class:`HandshakeDecision`). On
``ACCEPT`` the server derives the compatibility fingerprint itself and ends the connection if
its own differs: both sides must have agreed on the same fields, not only on "yes".

The fingerprint's canonical bytes are written out here byte by byte, as the document states
them, rather than left to a MessagePack library's choices: a library that wrote a whole-number
control rate as an integer, or a short string as ``str16``, would hash other bytes.
"""

from __future__ import annotations

import hashlib
import struct
from enum import StrEnum

import msgspec


class HandshakeVerdict(StrEnum):
    ACCEPT = "ACCEPT"
    REJECT = "REJECT"


class ClientHello(msgspec.Struct, frozen=True, kw_only=True):
    skill: str
    skill_version: str
    observation_keys: tuple[str, ...]
    action_dim: int
    action_units: str
    action_frame: str
    controller_mode: str
    control_rate_hz: float
    calibration_epoch: str
    queue_epoch: int
    protocol: tuple[int, int]
    reason_codes: tuple[str, ...]


class HandshakeOffer(msgspec.Struct, frozen=True, kw_only=True):
    policy_checkpoint: str
    config_hash: str
    observation_keys: tuple[str, ...]
    action_dim: int
    action_units: str
    action_frame: str
    chunk_horizon: int
    protocol: tuple[int, int]
    skill: str | None = None
    skill_version: str | None = None
    controller_mode: str | None = None
    calibration_epoch: int | str | None = None
    queue_epoch: int | None = None
    reason_codes: tuple[str, ...] | None = None
    rtc: bool = False
    """This server honours the committed prefix an observation carries (real-time chunking)."""


class HandshakeDecision(msgspec.Struct, frozen=True, kw_only=True):
    decision: HandshakeVerdict
    fingerprint: str | None = None
    reasons: tuple[str, ...] = ()
    protocol: int | None = None


def fingerprint(hello: ClientHello, offer: HandshakeOffer, protocol: int) -> str:
    """BLAKE2b with a 16-byte digest, as lower-case hex, over the agreed fields' canonical
    MessagePack array (``docs/protocol.md``, "The compatibility fingerprint").

    Raises:
        ValueError: an integer outside MessagePack's 64-bit range (a decoded hello cannot
            hold one; the check keeps the encoder total).
    """
    agreed = [
        protocol, offer.policy_checkpoint, offer.config_hash, list(hello.observation_keys),
        hello.action_dim, hello.action_units, hello.action_frame, offer.chunk_horizon,
        hello.skill, hello.skill_version, hello.controller_mode, float(hello.control_rate_hz),
        str(hello.calibration_epoch), hello.queue_epoch,
    ]
    return hashlib.blake2b(canonical_bytes(agreed), digest_size=16).hexdigest()


def canonical_bytes(value: int | float | str | list) -> bytes:  # type: ignore[type-arg]
    """The one MessagePack encoding the fingerprint hashes: every value in its shortest form,
    except floats, which are always float64. MessagePack numbers are big-endian."""
    if isinstance(value, int):
        return _canonical_int(value)
    if isinstance(value, float):
        return b"\xcb" + struct.pack(">d", value)
    if isinstance(value, str):
        data = value.encode("utf-8")
        return _str_header(len(data)) + data
    return _array_header(len(value)) + b"".join(canonical_bytes(item) for item in value)


def _canonical_int(value: int) -> bytes:
    if -32 <= value <= 0x7F:
        return struct.pack(">b", value) if value < 0 else bytes([value])  # the fixints
    forms = _UNSIGNED if value > 0 else _SIGNED
    for low, high, marker, fmt in forms:
        if low <= value <= high:
            return marker + struct.pack(fmt, value)
    raise ValueError(f"integer {value} does not fit in 64 bits")


_UNSIGNED = ((0, 0xFF, b"\xcc", ">B"), (0, 0xFFFF, b"\xcd", ">H"),
             (0, 0xFFFF_FFFF, b"\xce", ">I"), (0, 2**64 - 1, b"\xcf", ">Q"))
"""uint 8, 16, 32 and 64, tried in this order: a positive integer takes the first that fits."""
_SIGNED = ((-(2**7), -1, b"\xd0", ">b"), (-(2**15), -1, b"\xd1", ">h"),
           (-(2**31), -1, b"\xd2", ">i"), (-(2**63), -1, b"\xd3", ">q"))
"""int 8, 16, 32 and 64, for negative integers below the negative fixint range."""


def _str_header(length: int) -> bytes:
    if length <= 31:
        return bytes([0xA0 | length])  # fixstr
    if length <= 0xFF:
        return b"\xd9" + struct.pack(">B", length)  # str8
    if length <= 0xFFFF:
        return b"\xda" + struct.pack(">H", length)
    return b"\xdb" + struct.pack(">I", length)


def _array_header(length: int) -> bytes:
    if length <= 15:
        return bytes([0x90 | length])  # fixarray
    if length <= 0xFFFF:
        return b"\xdc" + struct.pack(">H", length)
    return b"\xdd" + struct.pack(">I", length)
