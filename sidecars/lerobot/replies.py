"""LeRobot's action replies, read without running them.

A reply is ``pickle.dumps(list[TimedAction])``, each ``TimedAction`` a dataclass of
``timestamp`` (float s), ``timestep`` (int) and ``action``, a torch tensor. A tensor pickles as
``torch._utils._rebuild_tensor_v2(storage, offset, size, stride, requires_grad, hooks)``, and
its storage as ``torch.storage._load_from_bytes(blob)``, where ``blob`` is the storage in
torch's legacy ``torch.save`` format: five pickles in a row (the magic number, the format
version 1001, the byte order and type sizes, the storage as a persistent id
``("storage", torch.FloatStorage, key, location, numel, None)``, the list of keys), then each
storage's element count as a little-endian int64 and its raw bytes. LeRobot reads it with
``torch.load(weights_only=False)``: any callable the pickle names, it runs.

Here an unpickler resolves exactly these names and nothing else: ``TimedAction`` (to a record
that checks its fields), ``_rebuild_tensor_v2`` (to a bounds-checked NumPy view),
``_load_from_bytes`` (to a reader of the legacy format built from unpicklers that resolve no
name at all but the storage types) and ``collections.OrderedDict`` (the empty backward hooks).
Anything else is refused, naming the global, before it is called.
"""

from __future__ import annotations

import collections
import io
import math
import pickle  # only through the restricted unpicklers below: find_class resolves a fixed set
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

TORCH_MAGIC = 0x1950A86A20F9469CFC6C
TORCH_LEGACY_VERSION = 1001
STORAGE_DTYPES: dict[str, np.dtype] = {
    "FloatStorage": np.dtype("<f4"), "DoubleStorage": np.dtype("<f8"),
    "HalfStorage": np.dtype("<f2"),
}
"""The storages an action may come in (little-endian; a big-endian blob is refused)."""
MOST_ELEMENTS = 1 << 20
"""A storage larger than this is refused (a 50×32 chunk holds 1,600)."""
MOST_ACTIONS = 1024
"""The longest reply read (warden's own limit on a chunk's rows)."""


class ReplyRefused(ValueError):
    """A reply that is not a list of ``TimedAction`` made of plain tensors, or names a global
    outside the allowed set. The message says which."""


@dataclass(frozen=True, slots=True)
class TimedActionRecord:
    timestamp: float
    timestep: int
    action: np.ndarray
    """1-D, float64."""


class _TimedActionState:
    """What ``NEWOBJ`` makes of ``TimedAction``: a shell that ``BUILD`` fills, checked."""

    __slots__ = ("record",)

    def __setstate__(self, state: object) -> None:
        if not isinstance(state, dict) or set(state) != {"timestamp", "timestep", "action"}:
            raise ReplyRefused("a TimedAction's fields are not timestamp, timestep, action")
        timestamp, timestep, action = state["timestamp"], state["timestep"], state["action"]
        if not isinstance(timestamp, float) or not math.isfinite(timestamp):
            raise ReplyRefused("a TimedAction's timestamp is not a finite float")
        if not isinstance(timestep, int) or isinstance(timestep, bool) or not (
                0 <= timestep < 2**63):
            raise ReplyRefused("a TimedAction's timestep is not a count")
        if not isinstance(action, _Tensor) or action.values.ndim != 1:
            raise ReplyRefused("a TimedAction's action is not a 1-D tensor")
        self.record = TimedActionRecord(timestamp, timestep, action.values.astype(np.float64))


@dataclass(frozen=True, slots=True)
class _Storage:
    values: np.ndarray
    """1-D, the storage's dtype."""


@dataclass(frozen=True, slots=True)
class _Tensor:
    values: np.ndarray


@dataclass(frozen=True, slots=True)
class _StorageType:
    dtype: np.dtype


def read_reply(data: bytes) -> list[TimedActionRecord]:
    """The actions of one ``Actions.data``.

    Raises:
        ReplyRefused: anything but a non-empty list of at most ``MOST_ACTIONS`` TimedActions.
    """
    try:
        value = _ReplyUnpickler(io.BytesIO(data)).load()
    except ReplyRefused:
        raise
    except Exception as error:  # a hostile pickle can raise anything the unpickler raises
        raise ReplyRefused(f"not a pickle LeRobot writes: {type(error).__name__}: "
                           f"{str(error)[:120]}") from None
    if not isinstance(value, list) or not 0 < len(value) <= MOST_ACTIONS:
        raise ReplyRefused(f"a reply is a list of 1 to {MOST_ACTIONS} TimedActions")
    if not all(isinstance(item, _TimedActionState) and hasattr(item, "record")
               for item in value):
        raise ReplyRefused("a reply's items are not all TimedActions")
    return [item.record for item in value]


class _Restricted(pickle.Unpickler):
    ALLOWED: ClassVar[dict[tuple[str, str], Any]] = {}
    """(module, name) → what the pickle gets for it; any other global is refused."""

    def find_class(self, module: str, name: str) -> Any:
        found = self.ALLOWED.get((module, name))
        if found is None:
            raise ReplyRefused(f"the global {module}.{name} is not allowed in a LeRobot reply")
        return found

    def persistent_load(self, pid: Any) -> Any:
        raise ReplyRefused("a persistent id outside a storage")


class _ReplyUnpickler(_Restricted):
    ALLOWED: ClassVar[dict[tuple[str, str], Any]] = {}  # filled below, once the functions exist


def _rebuild_tensor(storage: object, offset: object, size: object, stride: object,
                    requires_grad: object, hooks: object, metadata: object = None) -> _Tensor:
    """``torch._utils._rebuild_tensor_v2`` for a plain CPU tensor, as a copied NumPy view."""
    if not isinstance(storage, _Storage):
        raise ReplyRefused("a tensor over something that is not a storage")
    if not (_is_count(offset) and _counts(size) and _counts(stride)
            and len(size) == len(stride) <= 2):  # type: ignore[arg-type]
        raise ReplyRefused("a tensor's offset, size or stride is not a count")
    if math.prod(size) > MOST_ELEMENTS:  # type: ignore[arg-type]
        raise ReplyRefused(f"a tensor of more than {MOST_ELEMENTS} elements")  # a zero stride
    if requires_grad is not False or not isinstance(hooks, dict) or hooks or metadata:
        raise ReplyRefused("a tensor with gradients, hooks or metadata")
    values = storage.values
    if 0 in size:  # type: ignore[operator]
        return _Tensor(np.zeros(size, values.dtype))  # type: ignore[arg-type]
    last = offset + sum((n - 1) * s for n, s in zip(size, stride, strict=True))  # type: ignore
    if last >= values.size:
        raise ReplyRefused("a tensor reaches past its storage")
    view = np.lib.stride_tricks.as_strided(
        values[offset:], shape=size, strides=[s * values.itemsize for s in stride],
        writeable=False)
    return _Tensor(np.array(view))


def _load_storage(blob: object) -> _Storage:
    """``torch.storage._load_from_bytes``: one storage in torch's legacy format."""
    if not isinstance(blob, bytes):
        raise ReplyRefused("a storage that is not bytes")
    stream = io.BytesIO(blob)
    if _Plain(stream).load() != TORCH_MAGIC:
        raise ReplyRefused("a storage without torch's magic number")
    if _Plain(stream).load() != TORCH_LEGACY_VERSION:
        raise ReplyRefused("a storage of another torch format version")
    info = _Plain(stream).load()
    if not isinstance(info, dict) or info.get("little_endian") is not True:
        raise ReplyRefused("a storage written big-endian or without its byte order")
    declared = _StorageRoot(stream).load()
    if not isinstance(declared, _Declared):
        raise ReplyRefused("a storage blob whose object is not a storage")
    if _Plain(stream).load() != [declared.key]:
        raise ReplyRefused("a storage blob whose keys are not its one storage")
    count = int.from_bytes(stream.read(8), "little")
    data = stream.read(count * declared.dtype.itemsize + 1)
    if count != declared.numel or len(data) != count * declared.dtype.itemsize:
        raise ReplyRefused("a storage's element count or bytes do not match its declaration")
    return _Storage(np.frombuffer(data, dtype=declared.dtype))


@dataclass(frozen=True, slots=True)
class _Declared:
    key: str
    dtype: np.dtype
    numel: int


class _Plain(_Restricted):
    """Numbers, strings, lists and dicts only: resolves no global at all."""


class _StorageRoot(_Restricted):
    ALLOWED: ClassVar[dict[tuple[str, str], Any]] = {
        ("torch", name): _StorageType(dtype) for name, dtype in STORAGE_DTYPES.items()}

    def persistent_load(self, pid: Any) -> Any:
        if not (isinstance(pid, tuple) and len(pid) in (5, 6) and pid[0] == "storage"):
            raise ReplyRefused("a persistent id that is not a storage")
        _, kind, key, location, numel, *view = pid
        if not isinstance(kind, _StorageType) or not isinstance(key, str) or location != "cpu":
            raise ReplyRefused("a storage of another type, or not on the CPU")
        if not _is_count(numel) or numel > MOST_ELEMENTS or any(v is not None for v in view):
            raise ReplyRefused(f"a storage of more than {MOST_ELEMENTS} elements, or a view")
        return _Declared(key, kind.dtype, numel)


def _is_count(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= MOST_ELEMENTS


def _counts(value: object) -> bool:
    return isinstance(value, tuple) and all(_is_count(item) for item in value)


_ReplyUnpickler.ALLOWED = {
    ("lerobot.async_inference.helpers", "TimedAction"): _TimedActionState,
    ("torch._utils", "_rebuild_tensor_v2"): _rebuild_tensor,
    ("torch.storage", "_load_from_bytes"): _load_storage,
    ("collections", "OrderedDict"): collections.OrderedDict,
}
