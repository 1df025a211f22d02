"""The chunk envelope (docs/contract.md §1): scenario and wire decoders, payload hash."""

from __future__ import annotations

import math
from typing import Any

import msgspec
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from assurance.envelope import (
    MAX_ACTION_BYTES,
    Chunk,
    MalformedChunk,
    ReplacementPolicy,
    decode_wire_chunk,
    to_wire,
)
from assurance.event_chunk import decode_event_chunk

EVENT: dict[str, Any] = {
    "chunk_id": "c1", "sequence": 4, "queue_epoch": 2, "policy_checkpoint": "ckpt-a",
    "config_hash": "cfg-1", "skill": "insert", "skill_version": "1.2", "task_phase": "FREE_SPACE",
    "controller_mode": "position", "calibration_epoch": 7, "observation_id": "obs-9",
    "observation_event_time": 1.5, "observation_arrival_time": 2, "inference_start": 3,
    "inference_end": 40, "server_send": 41, "first_action_time": 60, "action_dt": 20,
    "last_action_time": 100, "max_observation_age": 80, "max_action_age": 150,
    "state_fingerprint": {"q": [0.0, 0.1], "hash": "h"}, "replacement_policy": "blend",
    "fallback_id": "hold", "actions": [[0.0, 0.1], [0.01, 0.11], [0.02, 0.12]],
}
REQUIRED = ("chunk_id", "sequence", "queue_epoch", "policy_checkpoint", "config_hash",
            "skill_version", "task_phase", "controller_mode", "calibration_epoch",
            "observation_id", "first_action_time", "action_dt", "actions")


def event(**changes: Any) -> dict[str, Any]:
    return {**EVENT, **changes}


def decoded(**changes: Any) -> Chunk:
    chunk = decode_event_chunk(event(**changes), client_receive=123)
    assert isinstance(chunk, Chunk), chunk
    return chunk


def malformed(ev: dict[str, Any]) -> MalformedChunk:
    result = decode_event_chunk(ev, client_receive=0)
    assert isinstance(result, MalformedChunk), result
    return result


# --- scenario events (ms) ------------------------------------------------------------------------


def test_valid_event_decodes_to_ns_times_and_read_only_actions() -> None:
    chunk = decoded()
    assert chunk.chunk_id == "c1" and chunk.sequence == 4 and chunk.queue_epoch == 2
    assert chunk.calibration_epoch == "7"
    assert chunk.time("observation_event_time") == 1_500_000
    assert chunk.time("first_action_time") == 60_000_000
    assert chunk.time("action_dt") == 20_000_000
    assert chunk.client_receive == 123
    assert chunk.horizon == 3 and chunk.actions.shape == (3, 2)
    assert chunk.actions.dtype == np.float64 and not chunk.actions.flags.writeable
    assert chunk.replacement_policy is ReplacementPolicy.BLEND
    assert chunk.fingerprint_q == (0.0, 0.1)
    assert chunk.nonfinite == ()
    assert chunk.clock_domain == "client"


def test_optional_fields_take_their_defaults() -> None:
    minimal = {name: EVENT[name] for name in REQUIRED}
    chunk = decode_event_chunk(minimal, 0)
    assert isinstance(chunk, Chunk)
    assert chunk.replacement_policy is ReplacementPolicy.REPLACE
    assert chunk.time("inference_start") is None and chunk.skill is None


@pytest.mark.parametrize("field", REQUIRED)
def test_each_missing_required_field_is_malformed_and_named(field: str) -> None:
    ev = event()
    del ev[field]
    result = malformed(ev)
    assert field in result.detail
    if field != "chunk_id":
        assert result.chunk_id == "c1"


@pytest.mark.parametrize(
    "actions",
    [[], [[]], [[1.0, 2.0], [3.0]], [[1.0], 2.0], [["a"]], [[True]], [[None]], "1,2", None,
     [[1.0, [2.0]]]],
)
def test_ragged_empty_or_non_numeric_actions_are_malformed(actions: Any) -> None:
    assert "actions" in malformed(event(actions=actions, last_action_time=None)).detail


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nonfinite_action_is_recorded_not_malformed(bad: float) -> None:
    chunk = decoded(actions=[[0.0, bad], [0.0, 0.0], [0.0, 0.0]])
    assert chunk.nonfinite == ("actions",)


@pytest.mark.parametrize("field", ["observation_event_time", "inference_start", "server_send",
                                   "first_action_time", "max_action_age"])
def test_nonfinite_time_field_is_recorded_by_name(field: str) -> None:
    chunk = decoded(**{field: math.nan})
    assert field in chunk.nonfinite
    assert chunk.time(field) is None


def test_nonfinite_fingerprint_is_recorded() -> None:
    assert decoded(state_fingerprint={"q": [math.inf, 0.0]}).nonfinite == ("state_fingerprint",)


def test_unknown_replacement_policy_is_malformed() -> None:
    assert "replacement_policy" in malformed(event(replacement_policy="overwrite")).detail


@pytest.mark.parametrize("last", [101, 99, 160])
def test_inconsistent_last_action_time_is_malformed(last: float) -> None:
    assert "last_action_time" in malformed(event(last_action_time=last)).detail


def test_last_action_time_within_rounding_is_accepted() -> None:
    decoded(last_action_time=100.0005)


@pytest.mark.parametrize("dt", [0, -20])
def test_non_positive_action_dt_is_malformed(dt: int) -> None:
    assert "action_dt" in malformed(event(action_dt=dt, last_action_time=None)).detail


@pytest.mark.parametrize(("field", "value"), [("sequence", "4"), ("sequence", 1.5),
                                              ("queue_epoch", True), ("chunk_id", ""),
                                              ("task_phase", None), ("inference_start", "3")])
def test_wrong_field_types_are_malformed(field: str, value: Any) -> None:
    assert field in malformed(event(**{field: value})).detail


# --- payload hash ------------------------------------------------------------------------------


def test_payload_hash_is_deterministic_and_ignores_transport_times() -> None:
    first = decoded()
    resend = decode_event_chunk(event(server_send=90, inference_end=89), client_receive=999)
    assert isinstance(resend, Chunk)
    assert first.payload_hash == decoded().payload_hash == resend.payload_hash


@pytest.mark.parametrize(("field", "value"), [("chunk_id", "c2"), ("sequence", 5),
                                              ("observation_id", "obs-10"),
                                              ("first_action_time", 61)])
def test_payload_hash_covers_identity_and_schedule(field: str, value: Any) -> None:
    assert decoded(**{field: value}, last_action_time=None).payload_hash != decoded().payload_hash


@given(st.integers(0, 2), st.integers(0, 1), st.floats(-10, 10, allow_nan=False))
def test_payload_hash_changes_when_any_action_changes(row: int, col: int, delta: float) -> None:
    actions = [list(r) for r in EVENT["actions"]]
    changed = actions[row][col] + delta
    actions[row][col] = changed
    chunk = decoded(actions=actions)
    if changed == EVENT["actions"][row][col]:
        assert chunk.payload_hash == decoded().payload_hash
    else:
        assert chunk.payload_hash != decoded().payload_hash


# --- wire frames (ns) --------------------------------------------------------------------------

finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@st.composite
def action_lists(draw: st.DrawFn) -> list[list[float]]:
    h, d = draw(st.integers(1, 8)), draw(st.integers(1, 7))
    row = st.lists(finite | st.sampled_from([math.nan, math.inf]), min_size=d, max_size=d)
    return draw(st.lists(row, min_size=h, max_size=h))


@given(action_lists(), st.integers(1, 10**6), st.integers(0, 10**12))
def test_wire_round_trip_keeps_hash_and_actions(
    actions: list[list[float]], dt_us: int, first_us: int
) -> None:
    chunk = decoded(actions=actions, action_dt=dt_us / 1000, first_action_time=first_us / 1000,
                    last_action_time=None)
    frame = msgspec.msgpack.encode(to_wire(chunk))
    back = decode_wire_chunk(frame, client_receive=5)
    assert isinstance(back, Chunk), back
    assert back.payload_hash == chunk.payload_hash
    np.testing.assert_array_equal(back.actions, chunk.actions)
    assert back.nonfinite == chunk.nonfinite
    assert back.time("first_action_time") == chunk.time("first_action_time")
    assert back.replacement_policy is chunk.replacement_policy
    assert back.fingerprint_q == chunk.fingerprint_q


def wire_dict(**changes: Any) -> dict[str, Any]:
    base = msgspec.to_builtins(to_wire(decoded()))
    base.update(changes)
    return base


def wire_actions(dtype: str = "<f8", shape: tuple[int, ...] = (3, 2), data: bytes | None = None
                 ) -> dict[str, Any]:
    if data is None:
        data = bytes(8 * math.prod(shape))  # 8-byte items for every dtype used here
    return {"dtype": dtype, "shape": list(shape), "data": data}


def wire_result(frame: bytes) -> Chunk | MalformedChunk:
    return decode_wire_chunk(frame, client_receive=0)


def test_other_float_dtypes_are_widened() -> None:
    data = np.arange(6, dtype=">f4").tobytes()
    chunk = wire_result(msgspec.msgpack.encode(wire_dict(actions=wire_actions(">f4", data=data))))
    assert isinstance(chunk, Chunk)
    np.testing.assert_array_equal(chunk.actions, np.arange(6.0).reshape(3, 2))


@pytest.mark.parametrize(
    "frame",
    [b"", b"\xc1", b"\xff" * 10, b"\x93\x01\x02\x03", msgspec.msgpack.encode({"chunk_id": 5}),
     msgspec.msgpack.encode(wire_dict())[:-7]],
    ids=["empty", "invalid-opcode", "garbage", "array", "wrong-type", "truncated"],
)
def test_garbage_and_truncated_frames_are_malformed(frame: bytes) -> None:
    assert isinstance(wire_result(frame), MalformedChunk)


@pytest.mark.parametrize(
    ("actions", "words"),
    [(wire_actions("<i8"), "float"), (wire_actions("garbage"), "dtype"),
     (wire_actions(shape=(6,)), "2-D"), (wire_actions(shape=(0, 2)), "2-D"),
     (wire_actions(data=b"\x00" * 47), "byte length"),
     (wire_actions(shape=(MAX_ACTION_BYTES // 8 + 1, 1)), "size limit")],
    ids=["int-dtype", "unknown-dtype", "1-d", "empty", "length", "oversized"],
)
def test_bad_action_payloads_are_malformed_with_the_id(actions: dict, words: str) -> None:
    result = wire_result(msgspec.msgpack.encode(wire_dict(actions=actions)))
    assert isinstance(result, MalformedChunk)
    assert result.chunk_id == "c1" and words in result.detail


@pytest.mark.parametrize(("field", "value"), [("action_dt", 0), ("chunk_id", ""),
                                              ("replacement_policy", "overwrite"),
                                              ("first_action_time", 15 * 10**18),
                                              ("observation_event_time", 2**64 - 1)])
def test_bad_wire_fields_are_malformed(field: str, value: Any) -> None:
    assert isinstance(wire_result(msgspec.msgpack.encode(wire_dict(**{field: value}))),
                      MalformedChunk)


@pytest.mark.parametrize("frame", [
    msgspec.msgpack.encode(wire_dict()).replace(b"c1", b"\xff\xfe", 1),  # invalid UTF-8
    b"\x91" * 100_000,  # arrays nested deeper than the stack
], ids=["invalid-utf8", "deep-nesting"])
def test_frames_msgspec_cannot_decode_are_malformed_not_raised(frame: bytes) -> None:
    assert isinstance(wire_result(frame), MalformedChunk)


@given(st.binary(max_size=96))
def test_random_bytes_never_raise(frame: bytes) -> None:
    assert isinstance(wire_result(frame), Chunk | MalformedChunk)


DTYPE_BUG = ("decode_wire_chunk: np.dtype() raises SyntaxError/ValueError (not TypeError) for "
             "dtype text like ',' or '8(', which _array_from_payload does not catch, so the "
             "frame raises instead of becoming a MalformedChunk")
OVERFLOW_BUG = ("decode_event_chunk: payload_hash's msgpack encoder raises OverflowError for "
                "ints outside int64/uint64 (sequence 2**64, first_action_time 1e300 ms) and "
                "float() overflows on huge int actions; it should return MalformedChunk")


@pytest.mark.parametrize("dtype", [",", "8(", "f8,("])
def test_unparsable_dtype_text_is_malformed_not_raised(dtype: str) -> None:
    frame = msgspec.msgpack.encode(wire_dict(actions=wire_actions("<f8") | {"dtype": dtype}))
    assert isinstance(wire_result(frame), MalformedChunk)


@pytest.mark.parametrize(("field", "value"), [("sequence", 2**64), ("first_action_time", 1e300),
                                              ("actions", [[10**400, 0.0]] * 3)])
def test_out_of_range_numbers_are_malformed_not_raised(field: str, value: Any) -> None:
    result = decode_event_chunk(event(**{field: value}, last_action_time=None), 0)
    assert isinstance(result, MalformedChunk)
