"""An unmodified openpi websocket server as a policy link: the same sans-I/O methods as
:class:`~kernel.shell.link_protocol.WardenProtocol`, over openpi's wire (:mod:`kernel.openpi_wire`).

openpi has no handshake, envelope, clock exchange or heartbeat: its server sends one metadata
map when the connection opens, then answers each observation map with one reply, strictly one
request at a time. So this object makes, honestly, what warden's gates need from what it knows
itself:

- **The offer** the core decides comes from the manifest's ``[policy.openpi]`` declarations and
  the robot's own hello: the schema is the robot's (openpi cannot state one), the checkpoint is
  what the manifest declares (openpi cannot attest it), and ``config_hash`` is
  ``openpi-sha256:<digest of the metadata frame>``, so the ``[[allowlist]]`` pins the server's
  configuration and a changed server is refused on reconnect.
- **Each chunk's envelope** comes from the one request in flight, on the robot's clock: its
  ``observation_id``, ``task_phase``, ``queue_epoch`` and state fingerprint are the
  observation's, ``observation_event_time`` is its oldest frame's capture time (its age counts
  from there), ``first_action_time`` the instant its joints were read (openpi's actions start
  at the state they were computed from: an expired prefix is trimmed or refused by the phase's
  rule), ``action_dt`` is the manifest's, ``chunk_id`` and ``sequence`` are the link's own. No
  server-side time is invented: ``inference_start``/``end`` stay absent.
- **The link's liveness** is the request's: a reply not back within the request timeout ends
  the connection as a silent peer (``HEARTBEAT_TIMEOUT``); a text frame (openpi's traceback
  before close code 1011) ends it with its first line logged; a frame that is not what openpi
  sends, or a reply of another action shape than the manifest's, is a protocol violation.

Nothing is sent for the robot's hello or the core's decision: openpi has no such messages, and
:attr:`OpenpiProtocol.says_goodbye` tells the client not to send warden's ``Bye`` either.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import msgspec
import numpy as np

from assurance.envelope import (
    ArrayPayload,
    MalformedChunk,
    StateFingerprint,
    WireChunk,
    decode_wire_chunk,
)
from assurance.handshake import ClientHello, HandshakeDecision, HandshakeOffer, HandshakeVerdict
from kernel.core import events as ev
from kernel.core.effects import ChunkDecision, DecisionRecord
from kernel.openpi_wire import OpenpiError, decode_metadata, decode_reply, encode_observation
from kernel.shell.link_protocol import (
    ChunksWaiting,
    Ended,
    Feed,
    HelloDue,
    ObservationDue,
    OfferArrived,
    Output,
    Send,
)
from kernel.shell.link_settings import PolicySettings
from kernel.shell.link_types import LinkCounters, LinkTiming, RobotSample
from kernel.wire import ByeReason

CONFIG_HASH_PREFIX = "openpi-sha256:"
_TEXT_SHOWN = 200
"""How much of a text frame (a server traceback) the link's end carries into the log."""


class OpenpiLink(msgspec.Struct, frozen=True, kw_only=True):
    """What the manifest says about the openpi server (``[policy.openpi]``, with
    ``[policy]``'s action period and horizon)."""

    policy_checkpoint: str
    """The checkpoint the server runs, as the deployment declares it (openpi cannot attest
    it: the allowlist pins it together with the metadata's digest)."""
    action_dt_ns: int
    max_horizon: int
    state_key: str = "observation/state"
    prompt_key: str = "prompt"
    prompt: str | None = None
    image_keys: dict[str, str] = {}
    """Camera name → the observation key the server reads its frames under."""

    @classmethod
    def of(cls, policy: PolicySettings) -> OpenpiLink:
        """From ``[policy]`` (its ``openpi`` table, its action period and chunk horizon)."""
        openpi = policy.openpi
        if openpi is None:
            raise ValueError('protocol = "openpi" needs [policy.openpi]')
        return cls(policy_checkpoint=openpi.policy_checkpoint,
                   action_dt_ns=round(policy.action_dt_ms * 1e6),
                   max_horizon=policy.chunk_horizon, state_key=openpi.state_key,
                   prompt_key=openpi.prompt_key, prompt=openpi.prompt,
                   image_keys=dict(openpi.images))


@dataclass(slots=True)
class _Request:
    observation_id: str
    t_event: int
    """The observation's time: its oldest frame's, else when the joints were read."""
    t_state: int
    """When the joints were read: openpi's first action follows the state."""
    queue_epoch: int
    task_phase: str
    q: tuple[float, ...]


class OpenpiProtocol:
    """openpi's websocket wire as a :class:`~kernel.shell.link_protocol.LinkProtocol`."""

    says_goodbye = False
    """openpi has no goodbye message: the client only closes the websocket."""

    def __init__(self, client_id: str, link: OpenpiLink, counters: LinkCounters,
                 timing: LinkTiming) -> None:
        self.client_id, self.link, self.counters, self.timing = client_id, link, counters, timing
        self.accepted = False
        self.version: int | None = None
        self.fingerprint: str | None = None
        self.clock = None  # the robot's clock is the only one: nothing to exchange
        self._sequence = itertools.count(1)
        self._observation_ids = itertools.count(1)
        self._open = False
        self._hello: ClientHello | None = None
        self._config_hash: str | None = None
        self._handshake_by: int | None = None
        self._in_flight: _Request | None = None
        self._reply_by: int | None = None
        self._waiting: tuple[np.ndarray, _Request] | None = None
        self._wanted = False

    # -- the connection --------------------------------------------------------------------

    def connect(self, now_ns: int) -> list[Output]:
        self.accepted, self.version, self._open = False, None, True
        self._hello = self._config_hash = None
        self._in_flight = self._waiting = None
        self._reply_by, self._wanted = None, False
        self._handshake_by = now_ns + self.timing.handshake_timeout_ns
        return [HelloDue()]

    def close(self) -> None:
        self._open = self._wanted = False
        self._handshake_by = self._reply_by = None
        self._in_flight = self._waiting = None

    def _end(self, bye: ByeReason | None, detail: str) -> list[Output]:
        self.close()
        return [Ended(bye, detail)]

    def hello(self, side: ClientHello, now_ns: int) -> list[Output]:
        if not self._open or self._hello is not None:
            return []
        self._hello = side
        return self._offer_arrived()

    def _offer_arrived(self) -> list[Output]:
        """The offer, once both the robot's hello and the server's metadata are in."""
        hello, config_hash = self._hello, self._config_hash
        if hello is None or config_hash is None or self._handshake_by is None:
            return []
        self._handshake_by = None
        return [OfferArrived(HandshakeOffer(
            policy_checkpoint=self.link.policy_checkpoint, config_hash=config_hash,
            observation_keys=hello.observation_keys, action_dim=hello.action_dim,
            action_units=hello.action_units, action_frame=hello.action_frame,
            chunk_horizon=self.link.max_horizon, protocol=hello.protocol))]

    # -- time ------------------------------------------------------------------------------

    def next_deadline(self) -> int | None:
        if not self._open:
            return None
        due = [d for d in (self._handshake_by, self._reply_by) if d is not None]
        return min(due) if due else None

    def timeout(self, now_ns: int) -> list[Output]:
        if not self._open:
            return []
        if self._handshake_by is not None and now_ns >= self._handshake_by:
            return self._end(ByeReason.HANDSHAKE_TIMEOUT, "no metadata frame in time")
        if self._reply_by is not None and now_ns >= self._reply_by:
            self.counters.link_timeouts += 1
            return self._end(ByeReason.HEARTBEAT_TIMEOUT,
                             f"no reply within {self.timing.request_timeout_ns / 1e9:.3f} s")
        return []

    # -- frames in -------------------------------------------------------------------------

    def receive_frame(self, data: bytes | str, now_ns: int) -> list[Output]:
        if not self._open:
            return []
        self.counters.frames_in += 1
        self.counters.bytes_in += len(data)
        if isinstance(data, str):  # openpi's traceback, before it closes with 1011
            first = next((line for line in data.strip().splitlines()[-1:]), "")
            return self._end(None, f"server error: {first[:_TEXT_SHOWN]}")
        try:
            return self._receive(data, now_ns)
        except OpenpiError as error:
            self.counters.protocol_violations += 1
            return self._end(ByeReason.PROTOCOL_VIOLATION, str(error))

    def _receive(self, data: bytes, now_ns: int) -> list[Output]:
        if self._config_hash is None:
            self._config_hash = CONFIG_HASH_PREFIX + decode_metadata(data).digest
            return self._offer_arrived()
        request = self._in_flight
        if request is None:
            raise OpenpiError("a reply to no request")
        hello = self._hello
        dim = hello.action_dim if hello is not None else 0
        actions = decode_reply(data, dim, self.link.max_horizon).actions  # checked at once
        self._in_flight, self._reply_by = None, None
        self._waiting = (actions, request)
        self.counters.chunks_in += 1
        return [ChunksWaiting()]

    def handshake_event(self, offer: HandshakeOffer, now_ns: int) -> ev.HandshakeEvent:
        return ev.HandshakeEvent(t=now_ns, offer=offer)

    # -- the core's decisions --------------------------------------------------------------

    def on_decision(self, record: DecisionRecord, queue_epoch: int,
                    now_ns: int) -> list[Output]:
        if isinstance(record, ChunkDecision):
            self.counters.chunk_decided(record.admitted)
            return []
        return self._decided(record)

    def _decided(self, decision: HandshakeDecision) -> list[Output]:
        if decision.decision != HandshakeVerdict.ACCEPT or decision.protocol is None:
            self.counters.handshakes_rejected += 1
            return self._end(None, "handshake rejected: " + ",".join(decision.reasons))
        self.counters.handshakes_accepted += 1
        self.accepted, self.version = True, decision.protocol
        self.fingerprint = decision.fingerprint
        self._wanted = False  # requests before the handshake are not for it
        return []

    # -- observations out, chunks in -------------------------------------------------------

    def request(self, now_ns: int) -> list[Output]:
        if not (self._open and self.accepted):
            return []
        self._wanted = True
        return self._observation_due()

    def _observation_due(self) -> list[Output]:
        """One request at a time: openpi answers them in order, on one connection."""
        if not self._wanted:
            return []
        if self._in_flight is not None or self._waiting is not None:
            self.counters.requests_waited += 1
            return []
        self._wanted = False
        return [ObservationDue()]

    def observe(self, sample: RobotSample, now_ns: int, queue_epoch: int) -> list[Output]:
        observation_id = f"{self.client_id}/{next(self._observation_ids)}"
        state = sample.q if sample.gripper is None else np.append(sample.q, sample.gripper)
        values: dict[str, np.ndarray | str | float] = {
            self.link.state_key: np.asarray(state, dtype=np.float64)}
        if self.link.prompt is not None:
            values[self.link.prompt_key] = self.link.prompt
        for image in sample.images:  # uint8 H×W×3, as openpi's image transforms take them
            values[self.link.image_keys[image.frame.camera]] = image.frame.image
        data = encode_observation(values)
        self._in_flight = _Request(observation_id, sample.taken_at(now_ns),
                                   sample.measured_at(now_ns), queue_epoch,
                                   str(sample.task_phase), tuple(float(v) for v in sample.q))
        self._reply_by = now_ns + self.timing.request_timeout_ns
        self.counters.observations_sent += 1
        stamps = tuple(image.stamp() for image in sample.images)
        return [Feed(ev.ObservationEvent(t=now_ns, observation_id=observation_id,
                                         frames=stamps)), Send(data)]

    @property
    def chunks_waiting(self) -> int:
        return int(self._waiting is not None) if self._open else 0

    @property
    def requests_in_flight(self) -> int:
        return int(self._in_flight is not None)

    def next_chunk(self, now_ns: int) -> list[Output]:
        waiting = self._waiting if self._open else None
        if waiting is None:
            return []
        self._waiting = None
        event = self.chunk_event(*waiting, now_ns)
        return [Feed(event), *self._observation_due()]

    def chunk_event(self, actions: np.ndarray, request: _Request,
                    now_ns: int) -> ev.ChunkEvent:
        """The reply's actions in an envelope made from their request, decoded as warden's own
        chunks are (every field bounded, the actions finite)."""
        hello = self._hello
        if hello is None or self._config_hash is None:
            raise RuntimeError("a chunk before the session was set up")
        sequence = next(self._sequence)
        body = msgspec.msgpack.encode(WireChunk(
            chunk_id=f"{self.client_id}/openpi-{sequence}", sequence=sequence,
            queue_epoch=request.queue_epoch, policy_checkpoint=self.link.policy_checkpoint,
            config_hash=self._config_hash, skill=hello.skill, skill_version=hello.skill_version,
            task_phase=request.task_phase, controller_mode=hello.controller_mode,
            calibration_epoch=hello.calibration_epoch, observation_id=request.observation_id,
            observation_event_time=request.t_event, first_action_time=request.t_state,
            action_dt=self.link.action_dt_ns, actions=ArrayPayload.from_array(actions),
            state_fingerprint=StateFingerprint(q=request.q)))
        chunk = decode_wire_chunk(body, now_ns)
        if isinstance(chunk, MalformedChunk):
            self.counters.malformed += 1
        return ev.ChunkEvent(now_ns, chunk, body)


__all__ = ["CONFIG_HASH_PREFIX", "OpenpiLink", "OpenpiProtocol"]
