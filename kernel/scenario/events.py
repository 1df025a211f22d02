"""Scenario events → core events, validated one by one (docs/contract.md §7, event table).

An invalid *event* (unknown kind, missing field, wrong dimension, time going backwards) makes
the file invalid and exits 2 naming it. A chunk's *content* is never a file error: whatever the
envelope holds, it is decoded into a chunk or a malformed chunk and refused with reason codes.
"""

from __future__ import annotations

import base64
import binascii
import math
from collections.abc import Callable, Mapping
from typing import Any

import msgspec

from assurance.clock import ms_to_ns
from assurance.envelope import decode_wire_chunk
from assurance.event_chunk import decode_event_chunk
from assurance.handshake import offer_in
from assurance.limits import JointLimits
from assurance.reasons import ReasonCode
from assurance.rtc import MAX_PREFIX_ROWS, RtcPrefix
from kernel.config.session import state_vector
from kernel.core.effects import Motion
from kernel.core.events import (
    CAMERA_STATUSES,
    CONTROLLER_STATUSES,
    LINK_STATUSES,
    OPERATOR_ACTIONS,
    RECORDER_FAULTS,
    REQUESTERS,
    CameraEvent,
    CameraStatus,
    ChunkEvent,
    ClockSyncEvent,
    ComputedEvent,
    ControllerEvent,
    ControllerStatus,
    Event,
    ForceEvent,
    FrameStamp,
    GripperEvent,
    HandshakeEvent,
    InsertEvent,
    LinkEvent,
    LinkStatus,
    MoveEvent,
    ObservationEvent,
    OodEvent,
    OperatorAction,
    OperatorEvent,
    PhaseEvent,
    RecorderEvent,
    RecorderFault,
    StateEvent,
    TickEvent,
)
from kernel.core.jobs import JobResult
from kernel.journal import COMMAND_ORIGINS, AppliedRecord, CommandOrigin, CommandRecord
from kernel.scenario.bounds import CLOCK_OFFSET_MAX_MS, EVENT_TIME_MAX_MS
from kernel.scenario.fields import (
    Where,
    choice,
    integer,
    is_number,
    mapping,
    number,
    text,
    vector,
)
from skills.phases import TaskPhase
from skills.task_fsm import Requester

Item = Event | CommandRecord
"""What a scenario or journal line is: an event for the core, or (journals) a command record
that a replay compares with the command it decides."""
Parser = Callable[[int, Mapping[str, Any], Where, JointLimits], Item]
MAX_FRAMES = 16
"""Cameras one observation may carry (a cell has two or three)."""


def parse_events(raw: Any, where: Where, limits: JointLimits) -> list[Item]:
    if not isinstance(raw, list):
        raise where.error("must be a list of events")
    events: list[Item] = []
    last = 0
    for index, item in enumerate(raw):
        here = where.at(index)
        if not isinstance(item, dict):
            raise here.error("must be an object with 't' and 'kind'")
        kind = item.get("kind")
        here = here.note(kind) if isinstance(kind, str) else here
        t = ms_to_ns(number(item, "t", here, minimum=0, maximum=EVENT_TIME_MAX_MS))
        if kind == "command":
            # Written once the driver has answered: events the policy link fed meanwhile may
            # come first. It names its tick's time, and is not an event for the core.
            pass
        elif t < last:
            raise here.error(f"time {item['t']} ms is earlier than the event before it")
        else:
            last = t
        parser = _PARSERS.get(kind) if isinstance(kind, str) else None
        if parser is None:
            raise here.at("kind").error(f"unknown event kind {kind!r} "
                                        f"(expected one of {', '.join(_PARSERS)})")
        events.append(parser(t, item, here, limits))
    return events


def _state(t: int, item: Mapping[str, Any], where: Where, limits: JointLimits) -> Event:
    if "q" not in item:
        raise where.error("missing required key 'q'")
    q = state_vector(item["q"], where.at("q"), limits, finite=False)
    qd = None
    if item.get("qd") is not None:
        qd = tuple(state_vector(item["qd"], where.at("qd"), limits, finite=False).tolist())
    residual = _residual(item.get("force_residual"), where.at("force_residual"))
    return StateEvent(t=t, q=tuple(q.tolist()), qd=qd, force_residual=residual)


def _residual(raw: Any, where: Where) -> float | None:
    """A residual is a number, or a vector reduced to its largest magnitude."""
    if raw is None:
        return None
    if is_number(raw):
        return float(raw)
    values = vector(raw, where, finite=False)
    if not values:
        raise where.error("must not be empty")
    if any(math.isnan(v) for v in values):
        return math.nan
    return max(values, key=abs)


def _observation(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    prefix = None if item.get("rtc") is None else _prefix(mapping(item, "rtc", where),
                                                           where.at("rtc"))
    return ObservationEvent(t=t, observation_id=text(item, "observation_id", where), rtc=prefix,
                            frames=_frames(item.get("frames", []), where.at("frames")))


def _frames(raw: Any, where: Where) -> tuple[FrameStamp, ...]:
    """The frames an observation carried: ``{camera, t_capture, digest, calibration_epoch}``
    (``t_capture`` exact, in ns)."""
    if not isinstance(raw, list) or len(raw) > MAX_FRAMES:
        raise where.error(f"must be a list of at most {MAX_FRAMES} frames")
    frames = []
    for index, entry in enumerate(raw):
        at = where.at(index)
        if not isinstance(entry, Mapping):
            raise at.error("must be an object")
        frames.append(FrameStamp(
            camera=text(entry, "camera", at, numbers_ok=False),
            t_capture=integer(entry, "t_capture", at, minimum=-MAX_EVENT_NS,
                              maximum=MAX_EVENT_NS),
            digest=text(entry, "digest", at, numbers_ok=False),
            calibration_epoch=text(entry, "calibration_epoch", at)))
    return tuple(frames)


def _camera(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    status = CameraStatus(choice(item, "status", where, CAMERA_STATUSES))
    detail = item.get("detail", "")
    if not isinstance(detail, str):
        raise where.at("detail").error("must be a string")
    return CameraEvent(t=t, camera=text(item, "camera", where, numbers_ok=False),
                       status=status, detail=detail)


def _prefix(item: Mapping[str, Any], where: Where) -> RtcPrefix:
    """The committed prefix an observation carried: ``actions`` (rows of numbers, one row per
    action of the grid), ``first_action_time_ns`` and ``action_dt_ns`` (exact), ``delay`` and
    ``horizon`` (actions)."""
    rows = item.get("actions")
    if not isinstance(rows, list) or len(rows) > MAX_PREFIX_ROWS or not all(
            isinstance(row, list) for row in rows):
        raise where.at("actions").error(
            f"must be a list of at most {MAX_PREFIX_ROWS} actions, each a list of numbers")
    actions = [vector(row, where.at("actions").at(i), len(rows[0]) if rows else None)
               for i, row in enumerate(rows)]
    return RtcPrefix(
        actions=tuple(tuple(float(v) for v in row) for row in actions),
        first_due=integer(item, "first_action_time_ns", where, minimum=-MAX_EVENT_NS,
                          maximum=MAX_EVENT_NS),
        action_dt=integer(item, "action_dt_ns", where, minimum=1, maximum=MAX_NS),
        delay=integer(item, "delay", where, minimum=0, maximum=MAX_PREFIX_ROWS),
        horizon=integer(item, "horizon", where, minimum=0, maximum=MAX_PREFIX_ROWS))


def _chunk(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    """Envelope fields in milliseconds, or (journals) the frame exactly as it arrived."""
    wire = item.get("wire")
    if wire is None:
        return ChunkEvent(t, decode_event_chunk(item, t))
    if not isinstance(wire, str):
        raise where.at("wire").error("must be the base64 text of a MessagePack frame")
    try:
        frame = base64.b64decode(wire, validate=True)
    except binascii.Error:
        raise where.at("wire").error("is not valid base64") from None
    return ChunkEvent(t, decode_wire_chunk(frame, t))


def _phase(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    to = TaskPhase(choice(item, "to", where, tuple(TaskPhase)))
    evidence = mapping(item, "evidence", where, required=False)
    by = Requester(choice(item, "by", where, REQUESTERS, default=Requester.FSM))
    return PhaseEvent(t=t, to=to, evidence=evidence, by=by)


def _force(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    if "residual" not in item:
        raise where.error("missing required key 'residual'")
    residual = _residual(item["residual"], where.at("residual"))
    return ForceEvent(t=t, residual=math.nan if residual is None else residual)


def _ood(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    score = item.get("score")
    if not is_number(score):
        raise where.at("score").error(f"must be a number, got {score!r}")
    # A score that is not a number cannot vouch for anything: treat it as out of distribution.
    return OodEvent(t=t, score=float(score) if math.isfinite(score) else math.inf)


def _link(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    return LinkEvent(t=t, status=LinkStatus(choice(item, "status", where, LINK_STATUSES)))


def _handshake(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    return HandshakeEvent(t=t, offer=offer_in(mapping(item, "offer", where)))


def _operator(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    uid = integer(item, "uid", where, minimum=0) if item.get("uid") is not None else None
    return OperatorEvent(t=t, action=OperatorAction(choice(item, "action", where,
                                                           OPERATOR_ACTIONS)), uid=uid)


def _controller(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    reason = None
    if item.get("reason") is not None:
        reason = ReasonCode(choice(item, "reason", where, tuple(ReasonCode)))
    status = ControllerStatus(choice(item, "status", where, CONTROLLER_STATUSES))
    return ControllerEvent(t=t, status=status,
                           reason=reason)


def _recorder(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    return RecorderEvent(t=t, fault=RecorderFault(choice(item, "fault", where, RECORDER_FAULTS)))


def _move(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    return MoveEvent(t=t, move_id=integer(item, "move_id", where, minimum=0),
                     target=tuple(vector(item.get("target"), where.at("target"))))


def _gripper(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    return GripperEvent(t=t, opening=number(item, "opening", where, minimum=0))


def _insert(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    return InsertEvent(t=t, xy=tuple(vector(item.get("xy"), where.at("xy"), 2)),
                       z_end=number(item, "z_end", where),
                       rotation=tuple(vector(item.get("rotation"), where.at("rotation"), 9)))


def _computed(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    return ComputedEvent(t=t, result=_converted(item.get("result"), JobResult,
                                                where.at("result")))


def _command(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Item:
    applied = item.get("applied")
    return CommandRecord(
        t=t, effect=_converted(item.get("effect"), Motion, where.at("effect")),
        applied=(None if applied is None
                 else _converted(applied, AppliedRecord, where.at("applied"))),
        origin=CommandOrigin(choice(item, "origin", where, COMMAND_ORIGINS,
                                    default=CommandOrigin.CORE)))


def _converted(raw: Any, kind: Any, where: Where) -> Any:
    try:
        return msgspec.convert(raw, kind)
    except msgspec.ValidationError as error:
        raise where.error(f"not a valid record: {error}") from None


MAX_NS = int(CLOCK_OFFSET_MAX_MS) * 1_000_000
"""The largest clock offset or round trip a file may carry (docs/manifest.md, "Bounds")."""
MAX_EVENT_NS = int(EVENT_TIME_MAX_MS) * 1_000_000
"""The largest event time a file may carry, in ns (a committed prefix's first due time)."""


def _clock_sync(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    # Journals carry integer nanoseconds (``offset_ns``): a policy host's clock can be far
    # enough from ours that milliseconds as a float would not round-trip to the nanosecond.
    if "offset_ns" in item or "round_trip_ns" in item:
        offset = integer(item, "offset_ns", where, minimum=-MAX_NS, maximum=MAX_NS)
        round_trip = integer(item, "round_trip_ns", where, minimum=0, maximum=MAX_NS)
    else:
        offset = ms_to_ns(number(item, "offset_ms", where, minimum=-CLOCK_OFFSET_MAX_MS,
                                 maximum=CLOCK_OFFSET_MAX_MS))
        round_trip = ms_to_ns(number(item, "round_trip_ms", where, minimum=0,
                                     maximum=CLOCK_OFFSET_MAX_MS))
    return ClockSyncEvent(t=t, domain=text(item, "domain", where), offset=offset,
                          round_trip=round_trip)


def _tick(t: int, item: Mapping[str, Any], where: Where, _: JointLimits) -> Event:
    return TickEvent(t=t, skipped=integer(item, "skipped", where, default=0, minimum=0))


_PARSERS: dict[str, Parser] = {
    "state": _state,
    "observation": _observation,
    "camera": _camera,
    "chunk": _chunk,
    "phase": _phase,
    "force": _force,
    "ood": _ood,
    "link": _link,
    "handshake": _handshake,
    "operator": _operator,
    "controller": _controller,
    "recorder": _recorder,
    "clock_sync": _clock_sync,
    "tick": _tick,
    "move": _move,
    "gripper": _gripper,
    "insert": _insert,
    "computed": _computed,
    "command": _command,
}
