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

Resolving only those names is not enough: the unpickler itself can be made to crash the
interpreter (a tuple nested 200,000 deep, hashed as a dict key), to allocate gigabytes (a memo
index of 2**27; a million-element tensor of stride 0 per row; one storage decoded again and
again) or to spend minutes (integer dict keys that all hash alike), and a ``BUILD`` aimed at
an allowed global could change it for every later reply. So before any unpickler runs, each
pickle's opcodes are read (``pickletools``, which executes nothing) against the few a LeRobot
reply uses, at most ``MOST_OPCODES`` of them, memo indices only in the order a pickler writes
them, nesting at most ``MOST_DEPTH`` deep and dict keys only text; what the allowed globals
give is a fresh object per reply that ``BUILD`` cannot change; and each reply has a budget of
calls, storage bytes and rebuilt elements, with every tensor one contiguous row of at most
``MOST_WIDTH`` values.
"""


from __future__ import annotations

import functools
import io
import math
import pickle  # only through the restricted unpicklers below: find_class resolves a fixed set
import pickletools  # reads opcodes without executing them
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

TORCH_MAGIC = 0x1950A86A20F9469CFC6C
TORCH_LEGACY_VERSION = 1001
STORAGE_DTYPES: dict[str, np.dtype] = {
    "FloatStorage": np.dtype("<f4"), "DoubleStorage": np.dtype("<f8"),
    "HalfStorage": np.dtype("<f2"),
}
"""The storages an action may come in (little-endian; a big-endian blob is refused)."""
MOST_ACTIONS = 1024
"""The longest reply read (warden's own limit on a chunk's rows)."""
MOST_WIDTH = 256
"""The widest action read (a bimanual arm with hands has tens of joints)."""
MOST_ELEMENTS = 1 << 20
"""A storage larger than this is refused (a 50 × 32 chunk holds 1,600)."""
MOST_OPCODES = 1 << 16
"""Opcodes in one pickle (a 50-row reply has about 2,000)."""
MOST_DEPTH = 24
"""How deep values may nest, counting every opcode that builds from others (a reply: 8)."""
MOST_CALLS = 4 * MOST_ACTIONS
MOST_STORAGE_BYTES = 16 << 20
"""Storage blobs decoded per reply, in bytes (a 50-row reply decodes 50 × 1.5 kB)."""
NAME_SHOWN = 60

_REPLY_OPCODES = frozenset({
    "PROTO", "FRAME", "STOP", "MARK", "EMPTY_LIST", "EMPTY_DICT", "EMPTY_TUPLE", "MEMOIZE",
    "BINPUT", "LONG_BINPUT", "BINGET", "LONG_BINGET", "SHORT_BINUNICODE", "BINUNICODE",
    "STACK_GLOBAL", "GLOBAL", "NEWOBJ", "BINFLOAT", "BININT", "BININT1", "BININT2", "LONG1",
    "SHORT_BINBYTES", "BINBYTES", "TUPLE", "TUPLE1", "TUPLE2", "TUPLE3", "REDUCE", "NEWFALSE",
    "NEWTRUE", "NONE", "SETITEM", "SETITEMS", "BUILD", "APPEND", "APPENDS",
})
"""What LeRobot's replies are written with (protocol 4), and the same at protocol 2."""
_STORAGE_OPCODES = frozenset({
    "PROTO", "STOP", "MARK", "EMPTY_LIST", "EMPTY_DICT", "MEMOIZE", "BINPUT", "LONG_BINPUT",
    "BINGET", "LONG_BINGET", "SHORT_BINUNICODE", "BINUNICODE", "GLOBAL", "BININT", "BININT1",
    "BININT2", "LONG1", "TUPLE", "NEWTRUE", "NEWFALSE", "NONE", "SETITEM", "SETITEMS",
    "APPEND", "APPENDS", "BINPERSID",
})
"""What torch's legacy ``torch.save`` of one storage is written with (protocol 2)."""
_TEXT = frozenset({"SHORT_BINUNICODE", "BINUNICODE"})
_MEMO_PUT = frozenset({"BINPUT", "LONG_BINPUT"})
_MEMO_GET = frozenset({"BINGET", "LONG_BINGET"})


class ReplyRefused(ValueError):
    """A reply that is not a list of ``TimedAction`` made of plain tensors, or names a global
    outside the allowed set, or breaks a bound. The message says which."""


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
        if hasattr(self, "record"):
            raise ReplyRefused("a TimedAction built twice")
        if not isinstance(state, dict) or set(state) != {"timestamp", "timestep", "action"}:
            raise ReplyRefused("a TimedAction's fields are not timestamp, timestep, action")
        timestamp, timestep, action = state["timestamp"], state["timestep"], state["action"]
        if not isinstance(timestamp, float) or not math.isfinite(timestamp):
            raise ReplyRefused("a TimedAction's timestamp is not a finite float")
        if not isinstance(timestep, int) or isinstance(timestep, bool) or not (
                0 <= timestep < 2**63):
            raise ReplyRefused("a TimedAction's timestep is not a count")
        if not isinstance(action, _Tensor):
            raise ReplyRefused("a TimedAction's action is not a 1-D tensor")
        self.record = TimedActionRecord(timestamp, timestep, action.values.astype(np.float64))


@dataclass(frozen=True, slots=True)
class _Storage:
    values: np.ndarray
    """1-D, the storage's dtype."""


@dataclass(frozen=True, slots=True)
class _Tensor:
    values: np.ndarray


class _Sealed:
    """What an allowed name gives a pickle: ``BUILD`` on it is refused (a reply must not
    change what the next one gets)."""

    __slots__ = ()

    def __setstate__(self, state: object) -> None:
        raise ReplyRefused("a BUILD on an allowed global")


class _Call(_Sealed):
    __slots__ = ("_function",)

    def __init__(self, function: Callable[..., object]) -> None:
        self._function = function

    def __call__(self, *args: object) -> object:
        return self._function(*args)


class _StorageType(_Sealed):
    __slots__ = ("dtype",)

    def __init__(self, dtype: np.dtype) -> None:
        self.dtype = dtype


@dataclass(slots=True)
class _Budget:
    """What one reply may cost, beyond its own size."""

    calls: int = 0
    storage_bytes: int = 0
    elements: int = 0
    seen: dict[int, _Storage] = field(default_factory=dict)
    """Storages decoded so far, by the blob's identity: one blob memoised and named again is
    decoded once."""

    def call(self) -> None:
        self.calls += 1
        if self.calls > MOST_CALLS:
            raise ReplyRefused(f"more than {MOST_CALLS} calls in one reply")


def read_reply(data: bytes) -> list[TimedActionRecord]:
    """The actions of one ``Actions.data``.

    Raises:
        ReplyRefused: anything but a non-empty list of at most ``MOST_ACTIONS`` TimedActions.
    """
    stream = io.BytesIO(data)
    try:
        _scan(stream, _REPLY_OPCODES)
        value = _ReplyUnpickler(stream).load()
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


def _scan(stream: io.BytesIO, allowed: frozenset[str]) -> None:
    """Read one pickle's opcodes from the stream's position without running them; the stream
    is left where it was.

    Raises:
        ReplyRefused: an opcode outside ``allowed``, too many, a memo index out of order,
            values nested deeper than ``MOST_DEPTH``, a dict key that is not text.
        ValueError: bytes that are not opcodes (pickletools' own complaint).
    """
    start = stream.tell()
    stack: list[tuple[int, bool] | None] = []
    """Per value: (how deep it nests, whether it is text); None: a mark."""
    memo: list[tuple[int, bool] | None] = []
    try:
        for count, (op, arg, _) in enumerate(pickletools.genops(stream)):
            if count >= MOST_OPCODES:
                raise ReplyRefused(f"more than {MOST_OPCODES} opcodes in one pickle")
            if op.name not in allowed:
                raise ReplyRefused(f"the opcode {op.name} is not one a LeRobot reply uses")
            _simulate(op, arg, stack, memo)
    finally:
        stream.seek(start)


def _simulate(op: pickletools.OpcodeInfo, arg: Any, stack: list[tuple[int, bool] | None],
              memo: list[tuple[int, bool] | None]) -> None:
    name = op.name
    if name in ("PROTO", "FRAME"):
        return
    if name == "MARK":
        stack.append(None)
        return
    if name == "MEMOIZE" or name in _MEMO_PUT:
        if name in _MEMO_PUT and arg != len(memo):
            raise ReplyRefused("a memo index out of the order a pickler writes them in")
        memo.append(_top(stack))
        return
    if name in _MEMO_GET:
        if not 0 <= arg < len(memo):
            raise ReplyRefused("a memo index never written")
        stack.append(memo[arg])
        return
    if name in ("SETITEM", "SETITEMS"):
        _text_keys(stack, name)
    popped = _pop(stack, op.stack_before)
    depth = 1 + max((item[0] for item in popped), default=-1)
    if depth > MOST_DEPTH:
        raise ReplyRefused(f"values nested more than {MOST_DEPTH} deep")
    stack.extend([(depth, name in _TEXT)] * len(op.stack_after))


def _top(stack: list[tuple[int, bool] | None]) -> tuple[int, bool] | None:
    if not stack:
        raise ReplyRefused("a pickle that takes from an empty stack")
    return stack[-1]


def _pop(stack: list[tuple[int, bool] | None],
         before: list[pickletools.StackObject]) -> list[tuple[int, bool]]:
    popped: list[tuple[int, bool]] = []
    for expected in reversed(before):
        if expected is pickletools.stackslice:
            while stack and stack[-1] is not None:
                popped.append(stack.pop())  # type: ignore[arg-type]
        elif expected is pickletools.markobject:
            if not stack or stack.pop() is not None:
                raise ReplyRefused("a pickle whose marks do not match")
        else:
            item = _top(stack)
            if item is None:
                raise ReplyRefused("a pickle whose marks do not match")
            popped.append(stack.pop())  # type: ignore[arg-type]
    return popped


def _text_keys(stack: list[tuple[int, bool] | None], name: str) -> None:
    """LeRobot's dicts are field names and features: a dict key that is not text is refused
    (integers that all hash alike would make building the dict quadratic)."""
    if name == "SETITEM":
        keys = stack[-2:-1]
    else:
        marks = [i for i, item in enumerate(stack) if item is None]
        keys = stack[marks[-1] + 1::2] if marks else []
    if not all(key is not None and key[1] for key in keys):
        raise ReplyRefused("a dict key that is not text")


class _Restricted(pickle.Unpickler):
    def __init__(self, file: io.BytesIO) -> None:
        super().__init__(file)
        self.allowed: dict[tuple[str, str], Callable[[], object]] = {}
        """(module, name) → what makes the object the pickle gets; any other is refused."""

    def find_class(self, module: str, name: str) -> Any:
        found = self.allowed.get((module, name))
        if found is None:
            raise ReplyRefused(f"the global {module[:NAME_SHOWN]}.{name[:NAME_SHOWN]} is not "
                               "allowed in a LeRobot reply")
        return found()

    def persistent_load(self, pid: Any) -> Any:
        raise ReplyRefused("a persistent id outside a storage")


class _ReplyUnpickler(_Restricted):
    def __init__(self, file: io.BytesIO) -> None:
        super().__init__(file)
        budget = _Budget()
        tensor = _Call(functools.partial(_rebuild_tensor, budget))
        storage = _Call(functools.partial(_load_storage, budget))
        hooks = _Call(_empty_hooks)
        self.allowed = {
            ("lerobot.async_inference.helpers", "TimedAction"): lambda: _TimedActionState,
            ("torch._utils", "_rebuild_tensor_v2"): lambda: tensor,
            ("torch.storage", "_load_from_bytes"): lambda: storage,
            ("collections", "OrderedDict"): lambda: hooks,
        }


def _empty_hooks(*args: object) -> dict[str, object]:
    """``collections.OrderedDict()``: a tensor's backward hooks, which must be none."""
    if args:
        raise ReplyRefused("backward hooks that are not empty")
    return {}


def _rebuild_tensor(budget: _Budget, storage: object, offset: object, size: object,
                    stride: object, requires_grad: object, hooks: object,
                    metadata: object = None) -> _Tensor:
    """``torch._utils._rebuild_tensor_v2`` for one contiguous row of a CPU storage, copied."""
    budget.call()
    if not isinstance(storage, _Storage):
        raise ReplyRefused("a tensor over something that is not a storage")
    if not (_is_count(offset) and isinstance(size, tuple) and len(size) == 1
            and _is_count(size[0]) and 0 < size[0] <= MOST_WIDTH and stride == (1,)):
        raise ReplyRefused(f"a tensor that is not one contiguous row of 1 to {MOST_WIDTH} "
                           "values")
    if requires_grad is not False or not isinstance(hooks, dict) or hooks or metadata:
        raise ReplyRefused("a tensor with gradients, hooks or metadata")
    end = offset + size[0]  # type: ignore[operator]
    if end > storage.values.size:
        raise ReplyRefused("a tensor reaches past its storage")
    budget.elements += size[0]
    if budget.elements > MOST_ACTIONS * MOST_WIDTH:
        raise ReplyRefused("more tensor values than a reply may hold")
    return _Tensor(storage.values[offset:end].copy())  # type: ignore[misc]


def _load_storage(budget: _Budget, blob: object) -> _Storage:
    """``torch.storage._load_from_bytes``: one storage in torch's legacy format."""
    budget.call()
    if not isinstance(blob, bytes):
        raise ReplyRefused("a storage that is not bytes")
    seen = budget.seen.get(id(blob))
    if seen is not None:
        return seen
    budget.storage_bytes += len(blob)
    if budget.storage_bytes > MOST_STORAGE_BYTES:
        raise ReplyRefused(f"more than {MOST_STORAGE_BYTES} bytes of storages in one reply")
    storage = _read_storage(io.BytesIO(blob))
    budget.seen[id(blob)] = storage
    return storage


def _read_storage(stream: io.BytesIO) -> _Storage:
    if _plain(stream) != TORCH_MAGIC:
        raise ReplyRefused("a storage without torch's magic number")
    if _plain(stream) != TORCH_LEGACY_VERSION:
        raise ReplyRefused("a storage of another torch format version")
    info = _plain(stream)
    if not isinstance(info, dict) or info.get("little_endian") is not True:
        raise ReplyRefused("a storage written big-endian or without its byte order")
    _scan(stream, _STORAGE_OPCODES)
    declared = _StorageRoot(stream).load()
    if not isinstance(declared, _Declared):
        raise ReplyRefused("a storage blob whose object is not a storage")
    if _plain(stream) != [declared.key]:
        raise ReplyRefused("a storage blob whose keys are not its one storage")
    count = int.from_bytes(stream.read(8), "little")
    data = stream.read(count * declared.dtype.itemsize + 1)
    if count != declared.numel or len(data) != count * declared.dtype.itemsize:
        raise ReplyRefused("a storage's element count or bytes do not match its declaration")
    return _Storage(np.frombuffer(data, dtype=declared.dtype))


def _plain(stream: io.BytesIO) -> object:
    """One pickle of numbers, text, lists and dicts: no global at all."""
    _scan(stream, _STORAGE_OPCODES - {"GLOBAL", "BINPERSID"})
    return _Restricted(stream).load()


@dataclass(frozen=True, slots=True)
class _Declared:
    key: str
    dtype: np.dtype
    numel: int


class _StorageRoot(_Restricted):
    STORAGES: ClassVar[frozenset[str]] = frozenset(STORAGE_DTYPES)

    def __init__(self, file: io.BytesIO) -> None:
        super().__init__(file)
        self.allowed = {("torch", name): functools.partial(_StorageType, dtype)
                        for name, dtype in STORAGE_DTYPES.items()}

    def persistent_load(self, pid: Any) -> Any:
        if not (isinstance(pid, tuple) and len(pid) in (5, 6) and pid[0] == "storage"):
            raise ReplyRefused("a persistent id that is not a storage")
        _, kind, key, location, numel, *view = pid
        if not isinstance(kind, _StorageType) or not isinstance(key, str) or location != "cpu":
            raise ReplyRefused("a storage of another type, or not on the CPU")
        if not _is_count(numel) or numel > MOST_ELEMENTS or any(v is not None for v in view):
            raise ReplyRefused(f"a storage of more than {MOST_ELEMENTS} elements, or a view")
        return _Declared(key[:NAME_SHOWN], kind.dtype, numel)


def _is_count(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= MOST_ELEMENTS
