"""openpi's websocket wire, as an unmodified ``openpi-server`` speaks it: pure encode and decode.

openpi (``openpi-client`` 0.1.2 / ``openpi-server`` 0.1.0) sends MessagePack in binary frames:
one *metadata* map right after the connection opens, then one reply map for each observation
map the client sends, strictly one request at a time. Arrays travel in ``msgpack_numpy``'s
layout, a map whose keys are MessagePack *bin* strings::

    {b"__ndarray__": True, b"data": <raw bytes>, b"dtype": "<f4", b"shape": [H, D]}

and NumPy scalars as ``{b"__npgeneric__": True, b"data": 2.0, b"dtype": "<f4"}``. A reply
holds ``actions`` (H×D) and ``server_timing`` (``infer_ms``; ``prev_total_ms`` from the second
request on, which includes the client's own idle time); a policy may add keys of its own. A
server-side exception arrives as a *text* frame holding the traceback, then close code 1011:
that is the transport's business (:mod:`kernel.shell`), not this module's.

Nothing here trusts the peer: the frame's size is bounded before decoding, every count and
shape entry before it is multiplied, the byte length of an array against its dtype and shape
before NumPy sees it, and every action value must be finite. A frame that breaks any of these
is a :class:`OpenpiError` naming what was wrong; the link treats it as a lost connection, and
the core never sees it. What openpi cannot tell (the action period, the checkpoint, any time on
the robot's clock) is not invented here: the link adds it from its own record of the request.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from typing import Any

import msgspec
import numpy as np

MAX_METADATA_BYTES = 1 << 16
"""The metadata map is operator-written configuration ({} or a reset pose): 64 KiB is ample."""
MAX_REPLY_BYTES = 1 << 20
"""A reply carries one action chunk; 1 MiB holds 1000 × 128 float64 actions."""
MAX_HORIZON = 1000
MAX_ACTION_DIM = 128
ACTION_DTYPES = frozenset({"<f4", "<f8", "<f2"})
"""Little-endian floats: what a policy's output transform produces."""
IMAGE_DTYPE = "|u1"

_ND = b"__ndarray__"
_SCALAR = b"__npgeneric__"


class OpenpiError(Exception):
    """A frame that is not what an openpi server sends; the message says what is wrong."""


class Metadata(msgspec.Struct, frozen=True):
    """The server's first frame: its digest (``config_hash`` of the chunks it will send, so a
    changed server is seen on reconnect) and its map as decoded (for the log)."""

    digest: str
    value: dict[str, Any]


class Reply(msgspec.Struct, frozen=True):
    """One reply: the actions (H×D float64, every value finite) and the server's own timing,
    which is on the server's clock and only logged."""

    actions: np.ndarray
    infer_ms: float | None


def decode_metadata(frame: bytes) -> Metadata:
    """The metadata map that opens every connection.

    Raises:
        OpenpiError: a frame over :data:`MAX_METADATA_BYTES`, not MessagePack, or not a map.
    """
    value = _decode_map(frame, MAX_METADATA_BYTES, "metadata")
    return Metadata(digest=hashlib.sha256(frame).hexdigest(),
                    value={str(key): item for key, item in value.items()})


def decode_reply(frame: bytes, action_dim: int, max_horizon: int = MAX_HORIZON) -> Reply:
    """A reply to one observation: ``actions`` must be an H×``action_dim`` float array with
    1 ≤ H ≤ ``max_horizon`` and only finite values.

    Raises:
        OpenpiError: naming what is wrong (size, layout, dtype, shape, a non-finite value).
    """
    reply = _decode_map(frame, MAX_REPLY_BYTES, "reply")
    if "actions" not in reply:
        raise OpenpiError(f"reply has no 'actions' (keys: {_keys(reply)})")
    actions = _array(reply["actions"], "actions", ACTION_DTYPES)
    if actions.ndim != 2:
        raise OpenpiError(f"actions must be H×D, got shape {actions.shape}")
    horizon, dim = actions.shape
    if not 1 <= horizon <= max_horizon:
        raise OpenpiError(f"actions hold {horizon} steps, expected 1 to {max_horizon}")
    if dim != action_dim:
        raise OpenpiError(f"actions have {dim} dimensions, the manifest maps {action_dim}")
    actions = actions.astype(np.float64)
    if not np.isfinite(actions).all():
        raise OpenpiError("actions hold a non-finite value")
    return Reply(actions=actions, infer_ms=_infer_ms(reply.get("server_timing")))


def encode_observation(values: Mapping[str, np.ndarray | str | float]) -> bytes:
    """An observation map as openpi's ``msgpack_numpy`` packs it: arrays in the bin-keyed
    layout, text and numbers as themselves. ``values``' keys are the server's own (the
    manifest maps warden's observation onto them)."""
    return msgspec.msgpack.encode({key: _packed(value) for key, value in values.items()})


def _packed(value: np.ndarray | str | float) -> Any:
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "VOc":
            raise OpenpiError(f"dtype {value.dtype} does not travel to openpi")
        array = np.ascontiguousarray(value)
        return {_ND: True, b"data": array.tobytes(), b"dtype": array.dtype.str,
                b"shape": list(array.shape)}
    return value


def _decode_map(frame: bytes, limit: int, what: str) -> dict[Any, Any]:
    if len(frame) > limit:
        raise OpenpiError(f"{what} frame of {len(frame)} bytes exceeds {limit}")
    try:
        value = msgspec.msgpack.decode(frame)
    except (ValueError, TypeError, RecursionError) as error:  # DecodeError, bad UTF-8, a map key
        raise OpenpiError(f"{what} frame is not MessagePack: {error}") from None
    if not isinstance(value, dict):
        raise OpenpiError(f"{what} frame must be a map, got {type(value).__name__}")
    return value


def _array(value: Any, name: str, dtypes: frozenset[str]) -> np.ndarray:
    if not isinstance(value, dict) or value.get(_ND) is not True:
        raise OpenpiError(f"{name} is not a msgpack_numpy array")
    dtype, shape, data = value.get(b"dtype"), value.get(b"shape"), value.get(b"data")
    if dtype not in dtypes:
        raise OpenpiError(f"{name} has dtype {dtype!r}, expected one of {sorted(dtypes)}")
    if not isinstance(shape, list) or not 1 <= len(shape) <= 4 or not all(
            type(n) is int and 0 <= n <= MAX_REPLY_BYTES for n in shape):
        raise OpenpiError(f"{name} has shape {shape!r}, expected 1 to 4 sizes")
    if not isinstance(data, bytes):
        raise OpenpiError(f"{name} carries no raw bytes")
    expected = math.prod(shape) * np.dtype(dtype).itemsize
    if len(data) != expected:
        raise OpenpiError(f"{name} holds {len(data)} bytes, its shape {shape} and dtype "
                          f"{dtype} need {expected}")
    return np.frombuffer(data, dtype=np.dtype(dtype)).reshape(shape)


def _infer_ms(timing: Any) -> float | None:
    if not isinstance(timing, dict):
        return None
    value = timing.get("infer_ms")
    if isinstance(value, dict) and value.get(_SCALAR) is True:
        value = value.get(b"data")
    if type(value) in (int, float) and math.isfinite(value) and 0 <= value <= 3.6e6:
        return float(value)
    return None


def _keys(value: Mapping[Any, Any]) -> str:
    return ", ".join(sorted(repr(key)[:40] for key in list(value)[:16]))


__all__ = ["MAX_ACTION_DIM", "MAX_HORIZON", "Metadata", "OpenpiError", "Reply",
           "decode_metadata", "decode_reply", "encode_observation"]
