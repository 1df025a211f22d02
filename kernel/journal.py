"""Run journals: the events a live run fed its core, in the scenario event format.

The first line is a header with ``"format": "warden-journal/1"`` and the same robot, timing,
phases, session, allowlist and motion sections as a scenario; every further line is one event
(times in milliseconds since the run started), ticks and job results included, or a
``command`` record: the motion effect the core decided on a tick, as it was written to the
driver, with the driver's answer (``applied``: accepted, reason, the driver's time).
``warden replay JOURNAL`` feeds the events to a fresh core, reproduces every decision of the
run and compares every command it decides with the recorded one, bit for bit. A chunk that came
off the wire is journaled as its frame (base64), so the replay decodes exactly the bytes the
run decoded.
"""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Callable, Mapping
from enum import StrEnum
from typing import IO, Any

import msgspec

from assurance.clock import ns_to_ms
from assurance.envelope import TIME_FIELDS, Chunk, MalformedChunk
from assurance.handshake import MalformedOffer, OfferIn
from assurance.reasons import ReasonCode
from assurance.rtc import RtcPrefix
from kernel.core.effects import Motion
from kernel.core.events import (
    CameraEvent,
    ChunkEvent,
    ClockSyncEvent,
    ComputedEvent,
    ControllerEvent,
    Event,
    ForceEvent,
    GripperEvent,
    HandshakeEvent,
    InsertEvent,
    LinkEvent,
    MoveEvent,
    ObservationEvent,
    OodEvent,
    OperatorEvent,
    PhaseEvent,
    RecorderEvent,
    StateEvent,
    TickEvent,
)

JOURNAL_FORMAT = "warden-journal/1"
HEADER_SECTIONS = ("robot", "timing", "phases", "session", "allowlist", "motion", "envelope",
                   "geometry", "cameras")


def header(sections: Mapping[str, Any], name: str) -> dict[str, Any]:
    """The journal's first line: the scenario sections that configure the core."""
    return {"format": JOURNAL_FORMAT, "name": name, **{k: sections[k] for k in HEADER_SECTIONS
                                                       if k in sections}}


class AppliedRecord(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    """The driver's answer to a command, as the journal records it."""

    accepted: bool
    reason: ReasonCode | None = None
    t_device_ns: int | None = None
    """The driver's own time stamp of the write (the host's monotonic clock, ns)."""


class CommandOrigin(StrEnum):
    """Who decided a command the journal records."""

    CORE = "core"
    """The tick's decision: a replay compares it with the one it decides."""
    SHELL = "shell"
    """The stop the shell writes when a tick fails: no decision to compare with."""


COMMAND_ORIGINS = tuple(CommandOrigin)


class CommandRecord(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    """One motion effect as it was written to the driver, and what the driver answered."""

    t: int
    effect: Motion
    applied: AppliedRecord | None = None
    origin: CommandOrigin = CommandOrigin.CORE


_record_encoder = msgspec.json.Encoder()


def command_line(record: CommandRecord) -> bytes:
    """The journal line of a command record (``t`` in ms, like every other line)."""
    body: dict[str, Any] = {"t": ns_to_ms(record.t), "kind": "command",
                            "effect": record.effect}
    if record.applied is not None:
        body["applied"] = record.applied
    if record.origin is not CommandOrigin.CORE:
        body["origin"] = record.origin
    return _record_encoder.encode(body)


def event_record(event: Event) -> dict[str, Any]:
    """One event as a scenario/journal dictionary."""
    record: dict[str, Any] = {"t": ns_to_ms(event.t)}
    record.update(_BODIES[type(event)](event))
    return record


def _state(event: StateEvent) -> dict[str, Any]:
    body: dict[str, Any] = {"kind": "state", "q": list(event.q)}
    if event.qd is not None:
        body["qd"] = list(event.qd)
    if event.force_residual is not None:
        body["force_residual"] = event.force_residual
    return body


def _chunk(event: ChunkEvent) -> dict[str, Any]:
    if event.frame is not None:
        chunk_id = event.chunk.chunk_id
        return {"kind": "chunk", "chunk_id": chunk_id,
                "wire": base64.b64encode(event.frame).decode("ascii")}
    if isinstance(event.chunk, MalformedChunk):
        raise ValueError("a malformed chunk can only be journaled with the frame it came in")
    return {"kind": "chunk", **chunk_fields(event.chunk)}


def chunk_fields(chunk: Chunk) -> dict[str, Any]:
    """The envelope of a decoded chunk in scenario form (milliseconds)."""
    fields: dict[str, Any] = {
        name: getattr(chunk, name) for name in (
            "chunk_id", "sequence", "queue_epoch", "policy_checkpoint", "config_hash",
            "skill_version", "task_phase", "controller_mode", "calibration_epoch",
            "observation_id", "clock_domain")
    }
    for name in (*TIME_FIELDS, "action_dt", "max_observation_age", "max_action_age"):
        value = chunk.times.get(name)
        if value is not None:
            fields[name] = ns_to_ms(value)
        elif name in chunk.nonfinite:
            fields[name] = math.nan  # which non-finite value it was does not change the refusal
    optional = {"skill": chunk.skill, "fallback_id": chunk.fallback_id,
                "action_units": chunk.action_units, "action_frame": chunk.action_frame}
    fields.update({k: v for k, v in optional.items() if v is not None})
    fields["replacement_policy"] = str(chunk.replacement_policy)
    if chunk.phase_markers:
        fields["phase_markers"] = list(chunk.phase_markers)
    if chunk.rtc_delay is not None:
        fields["rtc_delay"] = chunk.rtc_delay
    fields["actions"] = chunk.actions.tolist()
    return fields


def prefix_fields(prefix: RtcPrefix) -> dict[str, Any]:
    """An observation's committed prefix in file form (the grid's interval exact, in ns)."""
    return {"actions": [list(row) for row in prefix.actions],
            "first_action_time_ns": prefix.first_due, "action_dt_ns": prefix.action_dt,
            "delay": prefix.delay, "horizon": prefix.horizon}


def _offer(offer: OfferIn) -> Any:
    """An offer as it came: a malformed one's own fields, not its description."""
    return offer.raw if isinstance(offer, MalformedOffer) else msgspec.to_builtins(offer)


_BODIES: dict[type, Callable[[Any], dict[str, Any]]] = {
    StateEvent: _state,
    ChunkEvent: _chunk,
    ObservationEvent: lambda e: {"kind": "observation", "observation_id": e.observation_id,
                                 **({"rtc": prefix_fields(e.rtc)} if e.rtc else {}),
                                 **({"frames": [msgspec.to_builtins(f) for f in e.frames]}
                                    if e.frames else {})},
    CameraEvent: lambda e: {"kind": "camera", "camera": e.camera, "status": e.status,
                            **({"detail": e.detail} if e.detail else {})},
    PhaseEvent: lambda e: {"kind": "phase", "to": e.to, "evidence": dict(e.evidence),
                           "by": e.by},
    ForceEvent: lambda e: {"kind": "force", "residual": e.residual},
    OodEvent: lambda e: {"kind": "ood", "score": e.score},
    LinkEvent: lambda e: {"kind": "link", "status": e.status},
    HandshakeEvent: lambda e: {"kind": "handshake", "offer": _offer(e.offer)},
    OperatorEvent: lambda e: {"kind": "operator", "action": e.action,
                              **({"uid": e.uid} if e.uid is not None else {})},
    ControllerEvent: lambda e: {"kind": "controller", "status": e.status,
                                **({"reason": e.reason} if e.reason else {})},
    ClockSyncEvent: lambda e: {"kind": "clock_sync", "domain": e.domain,
                               "offset_ns": e.offset, "round_trip_ns": e.round_trip},
    TickEvent: lambda e: {"kind": "tick", **({"skipped": e.skipped} if e.skipped else {})},
    MoveEvent: lambda e: {"kind": "move", "move_id": e.move_id, "target": list(e.target)},
    GripperEvent: lambda e: {"kind": "gripper", "opening": e.opening},
    InsertEvent: lambda e: {"kind": "insert", "xy": list(e.xy), "z_end": e.z_end,
                            "rotation": list(e.rotation)},
    ComputedEvent: lambda e: {"kind": "computed", "result": msgspec.to_builtins(e.result)},
    RecorderEvent: lambda e: {"kind": "recorder", "fault": e.fault},
}


class JournalWriter:
    """Writes a journal to a text stream, one JSON document per line."""

    def __init__(self, stream: IO[str], head: Mapping[str, Any]) -> None:
        self._stream = stream
        self._stream.write(json.dumps(head, allow_nan=True) + "\n")
        self.events = 0

    def write(self, event: Event) -> None:
        self._stream.write(json.dumps(event_record(event), allow_nan=True) + "\n")
        self.events += 1

    def flush(self) -> None:
        self._stream.flush()
