"""Decoding a chunk event of a scenario or journal: envelope fields in milliseconds.

The same normalized :class:`~assurance.envelope.Chunk` as a wire frame decodes to; anything
that cannot be read is a :class:`~assurance.envelope.MalformedChunk`, never an exception.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from enum import StrEnum
from typing import Any

import numpy as np

from assurance.clock import CLIENT_DOMAIN, ms_to_ns
from assurance.envelope import (
    DURATION_FIELDS,
    REQUIRED_INT,
    REQUIRED_TEXT,
    TIME_FIELDS,
    UNTRUSTED_INPUT_ERRORS,
    Chunk,
    ChunkDecodeError,
    MalformedChunk,
    ReplacementPolicy,
    freeze_actions,
    identity_fields,
    is_number,
    payload_hash,
    phase_markers_of,
    salvage_id,
)


def decode_event_chunk(event: Mapping[str, Any], client_receive: int) -> Chunk | MalformedChunk:
    """Decode the envelope fields of a scenario ``chunk`` event (times in milliseconds)."""
    chunk_id = salvage_id(event.get("chunk_id"))
    try:
        return _decode_mapping(event, client_receive)
    except ChunkDecodeError as error:
        return MalformedChunk(chunk_id, str(error))
    except UNTRUSTED_INPUT_ERRORS as error:  # untrusted input never escapes as an exception
        return MalformedChunk(chunk_id, f"undecodable: {type(error).__name__}")


def _decode_mapping(event: Mapping[str, Any], client_receive: int) -> Chunk:
    fields: dict[str, Any] = {"chunk_id": _text_or_int(event, "chunk_id")}
    for name in REQUIRED_INT:
        fields[name] = _integer(event, name)
    for name in REQUIRED_TEXT:
        fields[name] = _text_or_int(event, name)
    fields["calibration_epoch"] = _text_or_int(event, "calibration_epoch")
    nonfinite: list[str] = []
    times: dict[str, int | None] = {}
    for name in (*TIME_FIELDS, *DURATION_FIELDS):
        times[name] = _milliseconds(event, name, nonfinite)
    for name in ("first_action_time", "action_dt"):
        if name not in event:
            raise ChunkDecodeError(f"missing required field {name!r}")
    if times["action_dt"] is not None and times["action_dt"] <= 0:
        raise ChunkDecodeError("action_dt must be positive")
    actions = _actions_from_lists(event.get("actions"), nonfinite)
    _check_last_action_time(event, times, actions.shape[0], nonfinite)
    return _build(event, fields, times, client_receive, actions, nonfinite)


def _build(
    event: Mapping[str, Any], fields: dict[str, Any], times: dict[str, int | None],
    client_receive: int, actions: np.ndarray, nonfinite: list[str],
) -> Chunk:
    policy = _enum(event, "replacement_policy", ReplacementPolicy, ReplacementPolicy.REPLACE)
    return Chunk(
        **fields,
        skill=_optional_text(event, "skill"),
        clock_domain=_optional_text(event, "clock_domain") or CLIENT_DOMAIN,
        client_receive=client_receive,
        times=times,
        replacement_policy=policy,
        fallback_id=_optional_text(event, "fallback_id"),
        phase_markers=phase_markers_of(event.get("phase_markers") or ()),
        action_units=_optional_text(event, "action_units"),
        action_frame=_optional_text(event, "action_frame"),
        fingerprint_q=_fingerprint(event.get("state_fingerprint"), nonfinite),
        actions=actions,
        nonfinite=tuple(nonfinite),
        payload_hash=payload_hash(
            identity_fields(fields), times["first_action_time"], times["action_dt"], actions
        ),
        rtc_delay=_rtc_delay(event.get("rtc_delay")),
    )


def _rtc_delay(value: Any) -> int | None:
    if value is None:
        return None
    if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 1024:
        raise ChunkDecodeError("field 'rtc_delay' must be an action count from 0 to 1024")
    return value


def _text_or_int(event: Mapping[str, Any], name: str) -> str:
    if name not in event:
        raise ChunkDecodeError(f"missing required field {name!r}")
    value = salvage_id(event[name])
    if value is None or value == "":
        raise ChunkDecodeError(f"field {name!r} must be a non-empty string")
    return value


def _optional_text(event: Mapping[str, Any], name: str) -> str | None:
    value = event.get(name)
    if value is None:
        return None
    if not isinstance(value, str):
        raise ChunkDecodeError(f"field {name!r} must be a string")
    return value


_INT64 = 2**63
MAX_TIME_MS = 1e13
"""Largest magnitude of a time in milliseconds (about 300 years): anything beyond is nonsense,
and would not fit the 64-bit integers of the wire."""


def _integer(event: Mapping[str, Any], name: str) -> int:
    if name not in event:
        raise ChunkDecodeError(f"missing required field {name!r}")
    value = event[name]
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, float) and math.isfinite(value) and value.is_integer():
            value = int(value)
        else:
            raise ChunkDecodeError(f"field {name!r} must be an integer")
    if not -_INT64 <= value < _INT64:
        raise ChunkDecodeError(f"field {name!r} is out of range")
    return value


def _milliseconds(event: Mapping[str, Any], name: str, nonfinite: list[str]) -> int | None:
    value = event.get(name)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ChunkDecodeError(f"field {name!r} must be a number of milliseconds")
    if isinstance(value, float) and not math.isfinite(value):
        nonfinite.append(name)
        return None
    if abs(value) > MAX_TIME_MS:
        raise ChunkDecodeError(f"field {name!r} is out of range")
    return ms_to_ns(value)


def _enum(event: Mapping[str, Any], name: str, enum: type[StrEnum], default: StrEnum) -> Any:
    value = event.get(name)
    if value is None:
        return default
    try:
        return enum(value)
    except ValueError:
        raise ChunkDecodeError(f"field {name!r} has unknown value {value!r}") from None


def _fingerprint(value: Any, nonfinite: list[str]) -> tuple[float, ...] | None:
    if value is None or isinstance(value, str):
        return None
    q = value.get("q") if isinstance(value, Mapping) else value
    if q is None:
        return None
    if not isinstance(q, list | tuple) or not all(is_number(v) for v in q):
        raise ChunkDecodeError("field 'state_fingerprint' must carry a joint vector 'q'")
    if not all(math.isfinite(v) for v in q):
        nonfinite.append("state_fingerprint")
    return tuple(float(v) for v in q)


def _actions_from_lists(value: Any, nonfinite: list[str]) -> np.ndarray:
    if not isinstance(value, list) or not value:
        raise ChunkDecodeError("field 'actions' must be a non-empty list of action vectors")
    width = len(value[0]) if isinstance(value[0], list) else -1
    for row in value:
        if not isinstance(row, list) or len(row) != width or width == 0:
            raise ChunkDecodeError("field 'actions' must be a rectangular H x D list of numbers")
        if not all(is_number(v) for v in row):
            raise ChunkDecodeError("field 'actions' holds a value that is not a number")
    try:
        array = np.array(value, dtype=np.float64)
    except OverflowError:
        raise ChunkDecodeError("field 'actions' holds a number too large for a float") from None
    return freeze_actions(array, nonfinite)


def _check_last_action_time(
    event: Mapping[str, Any], times: dict[str, int | None], horizon: int, nonfinite: list[str]
) -> None:
    last = _milliseconds(event, "last_action_time", nonfinite)
    first, dt = times["first_action_time"], times["action_dt"]
    if last is None or first is None or dt is None:
        return
    if abs(first + (horizon - 1) * dt - last) > 1_000:  # 1 us: rounding of ms in files
        raise ChunkDecodeError(
            "last_action_time disagrees with first_action_time + (H-1)*action_dt")
