"""LeRobot-shaped reply pickles assembled opcode by opcode, honest or hostile.

Python's pickler cannot write a global it cannot import (``torch._utils._rebuild_tensor_v2``,
``posix.system`` under another name), and a hostile pickle is precisely one whose globals are
chosen: so the tests write protocol-2 opcodes themselves. :func:`reply` with the defaults gives
what LeRobot's server sends (a list of ``TimedAction``, each tensor a row over a ``FloatStorage``
in torch's legacy format); each keyword changes one part.
"""

from __future__ import annotations

import pickle  # opcode constants only
import struct

import numpy as np

HELPERS = "lerobot.async_inference.helpers"
MAGIC = 0x1950A86A20F9469CFC6C


def global_(module: str, name: str) -> bytes:
    return pickle.GLOBAL + f"{module}\n{name}\n".encode()


def text(value: str) -> bytes:
    data = value.encode()
    return pickle.BINUNICODE + struct.pack("<I", len(data)) + data


def integer(value: int) -> bytes:
    return pickle.dumps(value, protocol=2)[2:-1]


def floating(value: float) -> bytes:
    return pickle.BINFLOAT + struct.pack(">d", value)


def binary(value: bytes) -> bytes:
    return pickle.BINBYTES + struct.pack("<I", len(value)) + value


def tuple_(*items: bytes) -> bytes:
    return pickle.MARK + b"".join(items) + pickle.TUPLE


def call(function: bytes, *args: bytes) -> bytes:
    return function + tuple_(*args) + pickle.REDUCE


def storage_blob(values: np.ndarray, storage: str = "FloatStorage", key: str = "k",
                 little_endian: bool = True, declared: int | None = None,
                 inner_global: bytes | None = None) -> bytes:
    """One storage as ``torch.save(storage, _use_new_zipfile_serialization=False)`` writes it."""
    header = (pickle.dumps(MAGIC, protocol=2) + pickle.dumps(1001, protocol=2) + pickle.dumps(
        {"protocol_version": 1001, "little_endian": little_endian,
         "type_sizes": {"short": 2, "int": 4, "long": 4}}, protocol=2))
    count = values.size if declared is None else declared
    pid = tuple_(text("storage"), inner_global or global_("torch", storage), text(key),
                 text("cpu"), integer(count), pickle.NONE)
    root = pickle.PROTO + b"\x02" + pid + pickle.BINPERSID + pickle.STOP
    keys = pickle.dumps([key], protocol=2)
    return header + root + keys + struct.pack("<q", values.size) + values.tobytes()


def tensor(blob: bytes, offset: int, size: tuple[int, ...], stride: tuple[int, ...],
           requires_grad: bool = False) -> bytes:
    return call(global_("torch._utils", "_rebuild_tensor_v2"),
                call(global_("torch.storage", "_load_from_bytes"), binary(blob)),
                integer(offset), tuple_(*map(integer, size)), tuple_(*map(integer, stride)),
                pickle.NEWTRUE if requires_grad else pickle.NEWFALSE,
                call(global_("collections", "OrderedDict")))


def timed_action(timestamp: float, timestep: int, action: bytes,
                 extra: dict[str, bytes] | None = None,
                 cls: bytes = global_(HELPERS, "TimedAction")) -> bytes:
    fields = [text("timestamp"), floating(timestamp), text("timestep"), integer(timestep),
              text("action"), action]
    for name, value in (extra or {}).items():
        fields += [text(name), value]
    return (cls + pickle.EMPTY_TUPLE + pickle.NEWOBJ + pickle.EMPTY_DICT + pickle.MARK
            + b"".join(fields) + pickle.SETITEMS + pickle.BUILD)


def reply(actions: np.ndarray, t0: float = 12.5, step0: int = 0, fps: float = 30.0,
          dtype: str = "<f4") -> bytes:
    """An honest reply: each row a tensor over the whole chunk's storage, as LeRobot sends."""
    blob = storage_blob(np.ascontiguousarray(actions, dtype=dtype).reshape(-1),
                        storage="FloatStorage" if dtype == "<f4" else "DoubleStorage")
    rows, width = actions.shape
    items = [timed_action(t0 + i / fps, step0 + i, tensor(blob, i * width, (width,), (1,)))
             for i in range(rows)]
    return listing(*items)


def listing(*items: bytes) -> bytes:
    return (pickle.PROTO + b"\x02" + pickle.EMPTY_LIST + pickle.MARK + b"".join(items)
            + pickle.APPENDS + pickle.STOP)
