"""The LeRobot sidecar reads replies without running them: bytes captured from a real LeRobot
0.4.4 server decode to the values torch itself read from them, and every hostile pickle is
refused before anything it names is called (tests/interop/lerobot/captured/provenance.json)."""

from __future__ import annotations

import contextlib
import json
import pickle
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sidecars.lerobot.replies import MOST_ACTIONS, MOST_ELEMENTS, ReplyRefused, read_reply
from tests.sidecars import pickle_assembler as asm

CAPTURED = Path(__file__).parents[1] / "interop" / "lerobot" / "captured"
PROVENANCE = json.loads((CAPTURED / "provenance.json").read_text())
CANARY_CALLS: list[str] = []


def canary(*args: object) -> None:
    """What a hostile reply names: it must never be called."""
    CANARY_CALLS.append(repr(args))


@pytest.mark.parametrize("index", range(len(PROVENANCE["replies"])))
def test_a_real_servers_reply_reads_as_torch_read_it(index: int) -> None:
    expected = PROVENANCE["replies"][index]
    data = (CAPTURED / expected["file"]).read_bytes()
    assert len(data) == expected["bytes"]
    records = read_reply(data)
    assert [r.timestep for r in records] == expected["timesteps"]
    assert [r.timestamp for r in records] == expected["timestamps"]
    actions = np.stack([r.action for r in records])
    assert expected["dtype"] == "torch.float32"
    assert np.array_equal(actions, np.array(expected["actions"], dtype=np.float32))
    assert actions.dtype == np.float64


def test_the_assembled_honest_reply_reads_back() -> None:
    actions = np.arange(12, dtype=np.float32).reshape(4, 3) / 7
    records = read_reply(asm.reply(actions, t0=3.25, step0=9))
    assert [r.timestep for r in records] == [9, 10, 11, 12]
    assert np.array_equal(np.stack([r.action for r in records]), actions.astype(np.float64))
    doubles = read_reply(asm.reply(actions.astype(np.float64), dtype="<f8"))
    assert np.array_equal(np.stack([r.action for r in doubles]), actions.astype(np.float64))


def _one(action: bytes, **changes: object) -> bytes:
    return asm.listing(asm.timed_action(1.0, 0, action, **changes))  # type: ignore[arg-type]


def _row(values: np.ndarray | None = None, **blob: object) -> bytes:
    values = np.zeros(6, np.float32) if values is None else values
    return asm.tensor(asm.storage_blob(values, **blob), 0, (values.size,), (1,))  # type: ignore


HOSTILE = {
    "os.system in place of the list": (
        b"\x80\x02" + asm.call(asm.global_("posix", "system"), asm.text("touch /tmp/x")) + b".",
        "posix.system is not allowed"),
    "a canary called as the action": (
        _one(asm.call(asm.global_(__name__, "canary"), asm.text("x"))),
        f"{__name__}.canary is not allowed"),
    "eval through builtins": (
        b"\x80\x02" + asm.call(asm.global_("builtins", "eval"), asm.text("1+1")) + b".",
        "builtins.eval is not allowed"),
    "a dotted name through an allowed class": (
        _one(asm.call(asm.global_("collections", "OrderedDict.fromkeys"), asm.text("ab"))),
        "collections.OrderedDict.fromkeys is not allowed"),
    "a global inside the storage blob": (
        _one(_row(inner_global=asm.global_("posix", "system"))),
        "posix.system is not allowed"),
    "a LongStorage": (_one(_row(storage="LongStorage")), "torch.LongStorage is not allowed"),
    "a big-endian storage": (_one(_row(little_endian=False)), "big-endian"),
    "a storage that declares more than it holds": (
        _one(_row(declared=7)), "count or bytes do not match"),
    "a tensor past its storage": (
        _one(asm.tensor(asm.storage_blob(np.zeros(6, np.float32)), 3, (6,), (1,))),
        "reaches past its storage"),
    "a zero-stride tensor of a trillion elements": (
        _one(asm.tensor(asm.storage_blob(np.zeros(6, np.float32)), 0, (MOST_ELEMENTS,
                                                                         MOST_ELEMENTS), (0, 0))),
        "not one contiguous row"),
    "a zero-stride row of a million values": (
        _one(asm.tensor(asm.storage_blob(np.zeros(1, np.float32)), 0, (MOST_ELEMENTS,), (0,))),
        "not one contiguous row"),
    "a tensor that needs gradients": (
        _one(asm.tensor(asm.storage_blob(np.zeros(6, np.float32)), 0, (6,), (1,),
                        requires_grad=True)), "gradients"),
    "an action that is a list": (_one(b"](K\x01K\x02e"), "not a 1-D tensor"),
    "a TimedAction with another field": (
        _one(_row(), extra={"__reduce__": asm.text("x")}), "fields are not"),
    "another LeRobot class": (
        _one(_row(), cls=asm.global_(asm.HELPERS, "TimedObservation")),
        "TimedObservation is not allowed"),
    "a timestep that is negative": (
        asm.listing(asm.timed_action(1.0, -1, _row())), "timestep is not a count"),
    "a timestamp that is NaN": (
        asm.listing(asm.timed_action(float("nan"), 0, _row())), "not a finite float"),
    "an empty list": (asm.listing(), "a list of 1 to"),
    "a dict in place of the list": (pickle.dumps({"actions": [1.0]}), "a list of 1 to"),
    "a list of plain numbers": (pickle.dumps([1.0, 2.0]), "not all TimedActions"),
    "a persistent id outside a storage": (b"\x80\x02X\x01\x00\x00\x00aQ.",
                                          "opcode BINPERSID is not one"),
    # Found by a red-team review (each crashed, exhausted memory or time, or poisoned later
    # replies before the opcode scan and the sealed globals):
    "a tuple nested 200,000 deep, hashed as a dict key": (
        b"\x80\x02}" + b")" + b"\x85" * 200_000 + b"K\x01s.", "nested more than"),
    "a memo index of 2**27": (b"\x80\x02Nr\x00\x00\x00\x08.", "memo index out of the order"),
    "integer dict keys that all hash alike": (
        b"\x80\x02}(" + b"".join(asm.integer(i * (2**61 - 1)) + b"N" for i in range(50))
        + b"u.", "a dict key that is not text"),
    "a million empty sets": (b"\x80\x04(" + b"\x8f" * 1000 + b"l.", "opcode EMPTY_SET"),
    "an extension code": (b"\x80\x02\x82\x01.", "opcode EXT1"),
    "a BUILD that would rewrite an allowed global": (
        b"\x80\x02" + asm.global_("torch._utils", "_rebuild_tensor_v2") + b"N}"
        + asm.text("__defaults__") + b"K\x01\x85s\x86b.", "a BUILD on an allowed global"),
    "a BUILD inside a storage blob": (
        _one(_row(inner_global=asm.global_("torch", "FloatStorage")
                  + asm.tuple_(asm.text("x")) + b"b")), "opcode BUILD is not one"),
    "a global named by four megabytes": (
        b"\x80\x02c" + b"m" * (4 << 20) + b"\nx\n.", "the global m{60}\\.x is not"),
    "bytes that are no pickle": (b"\x00\x01garbage", "not a pickle LeRobot writes"),
}


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_a_hostile_reply_is_refused_before_anything_runs(name: str) -> None:
    """And leaves nothing behind: the real reply read next reads as before."""
    data, message = HOSTILE[name]
    pattern = message if "\\" in message else message.replace(".", r"\.")
    with pytest.raises(ReplyRefused, match=pattern) as refused:
        read_reply(data)
    assert len(str(refused.value)) < 400
    assert CANARY_CALLS == []
    test_a_real_servers_reply_reads_as_torch_read_it(0)


def test_one_storage_named_again_and_again_is_decoded_once_within_a_budget() -> None:
    blob = asm.storage_blob(np.arange(6, dtype=np.float32))
    first = (asm.global_("torch.storage", "_load_from_bytes") + b"q\x00"  # memo 0: the call
             + b"(" + asm.binary(blob) + b"q\x01tR")  # memo 1: the blob
    again = b"h\x00(h\x01tR" * 5000
    with pytest.raises(ReplyRefused, match="more than 4096 calls"):
        read_reply(b"\x80\x02](" + first + again + b"e.")


def test_a_cut_real_reply_is_refused() -> None:
    data = (CAPTURED / PROVENANCE["replies"][0]["file"]).read_bytes()
    for cut in (10, len(data) // 2, len(data) - 1):
        with pytest.raises(ReplyRefused):
            read_reply(data[:cut])


def test_a_reply_longer_than_a_chunk_may_be_is_refused() -> None:
    row = asm.timed_action(1.0, 0, _row())
    with pytest.raises(ReplyRefused, match="a list of 1 to"):
        read_reply(asm.listing(*[row] * (MOST_ACTIONS + 1)))


@given(st.binary(max_size=400))
def test_no_bytes_escape_as_anything_but_a_refusal(data: bytes) -> None:
    with contextlib.suppress(ReplyRefused):
        read_reply(data)
    assert CANARY_CALLS == []


@given(st.integers(0, 75_000), st.binary(min_size=1, max_size=8))
def test_a_corrupted_real_reply_reads_or_is_refused(at: int, junk: bytes) -> None:
    data = bytearray((CAPTURED / PROVENANCE["replies"][0]["file"]).read_bytes())
    data[at:at + len(junk)] = junk
    try:
        records = read_reply(bytes(data))
    except ReplyRefused:
        return
    assert 0 < len(records) <= MOST_ACTIONS
    assert all(r.action.ndim == 1 and r.action.dtype == np.float64 for r in records)
