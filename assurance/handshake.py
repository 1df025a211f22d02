"""The compatibility handshake (docs/contract.md §5).

Before the first chunk of a session the client states its side (:class:`ClientHello`), the server
offers its side (:class:`HandshakeOffer`), and the client decides: ``ACCEPT`` with a fingerprint
both sides derive from the same fields, or ``REJECT`` with every reason that applies. A rejected
session leaves the queue empty. "Connected" is never a result, and reconnecting never waives the
check.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import msgspec

from assurance.reasons import ReasonCode, canonical, is_known


class ClientHello(msgspec.Struct, frozen=True, kw_only=True):
    skill: str
    skill_version: str
    observation_keys: tuple[str, ...]
    action_dim: int
    action_units: str
    action_frame: str
    controller_mode: str
    control_rate_hz: float
    calibration_epoch: str
    queue_epoch: int
    protocol: tuple[int, int]
    reason_codes: tuple[str, ...]


class HandshakeOffer(msgspec.Struct, frozen=True, kw_only=True):
    policy_checkpoint: str
    config_hash: str
    observation_keys: tuple[str, ...]
    action_dim: int
    action_units: str
    action_frame: str
    chunk_horizon: int
    protocol: tuple[int, int]
    skill: str | None = None
    skill_version: str | None = None
    controller_mode: str | None = None
    calibration_epoch: int | str | None = None
    queue_epoch: int | None = None
    reason_codes: tuple[str, ...] | None = None
    rtc: bool = False
    """The server honours a committed prefix (real-time chunking, assurance/rtc.py): warden
    sends one with each observation, and its chunks may say they were conditioned on it."""


class HandshakeVerdict(StrEnum):
    """A handshake's result (docs/contract.md §5): "connected" is not one."""

    ACCEPT = "ACCEPT"
    REJECT = "REJECT"


class HandshakeDecision(msgspec.Struct, frozen=True, kw_only=True):
    decision: HandshakeVerdict
    fingerprint: str | None = None
    reasons: tuple[str, ...] = ()
    protocol: int | None = None


@dataclass(frozen=True, slots=True)
class Session:
    """What an accepted handshake established."""

    policy_checkpoint: str
    config_hash: str
    fingerprint: str
    protocol: int
    chunk_horizon: int


AllowList = frozenset[tuple[str, str]]


class MalformedOffer(msgspec.Struct, frozen=True, kw_only=True):
    """An offer that does not decode (a scenario's or a hand-edited journal's: the wire decoder
    lets none through): what it said, kept to be journaled as it came, and why it is refused."""

    raw: dict[str, Any]
    detail: str


OfferIn = HandshakeOffer | MalformedOffer
"""An offer as the core receives it: typed, or typed as malformed."""


def decode_offer(offer: Mapping[str, Any] | HandshakeOffer) -> HandshakeOffer | str:
    """A typed offer, or a short description of why it is malformed."""
    if isinstance(offer, HandshakeOffer):
        return offer
    try:
        return msgspec.convert(offer, HandshakeOffer)
    except msgspec.ValidationError as error:
        return str(error)


def offer_in(offer: Mapping[str, Any]) -> OfferIn:
    """An offer read from a document (a scenario, a journal), typed once, at the boundary."""
    typed = decode_offer(offer)
    return MalformedOffer(raw=dict(offer), detail=typed) if isinstance(typed, str) else typed


def evaluate(
    hello: ClientHello, offer: Mapping[str, Any] | OfferIn, allowlist: AllowList
) -> tuple[HandshakeDecision, Session | None]:
    """Decide on an offer. All checks run; a rejection lists every reason that applies."""
    typed = offer.detail if isinstance(offer, MalformedOffer) else decode_offer(offer)
    if isinstance(typed, str):
        return HandshakeDecision(decision=HandshakeVerdict.REJECT,
                                 reasons=(ReasonCode.MALFORMED,)), None
    reasons = list(_mismatches(hello, typed, allowlist))
    version = _common_protocol(hello.protocol, typed.protocol)
    if version is None:
        reasons.append(ReasonCode.PROTOCOL_MISMATCH)
    if reasons or version is None:
        return HandshakeDecision(decision=HandshakeVerdict.REJECT, reasons=canonical(reasons)), None
    print_ = fingerprint(hello, typed, version)
    session = Session(typed.policy_checkpoint, typed.config_hash, print_, version,
                      typed.chunk_horizon)
    return HandshakeDecision(decision=HandshakeVerdict.ACCEPT, fingerprint=print_,
                             protocol=version), session


def _mismatches(
    hello: ClientHello, offer: HandshakeOffer, allowlist: AllowList
) -> Iterable[ReasonCode]:
    if offer.chunk_horizon <= 0 or offer.action_dim <= 0:
        yield ReasonCode.MALFORMED
    if (offer.policy_checkpoint, offer.config_hash) not in allowlist:
        yield ReasonCode.CHECKPOINT_NOT_ALLOWED
    schema = (offer.observation_keys, offer.action_dim, offer.action_units, offer.action_frame)
    if schema != (hello.observation_keys, hello.action_dim, hello.action_units,
                  hello.action_frame):
        yield ReasonCode.SCHEMA_MISMATCH
    if _differs(offer.skill, hello.skill) or _differs(offer.skill_version, hello.skill_version):
        yield ReasonCode.SKILL_MISMATCH
    if _differs(offer.controller_mode, hello.controller_mode):
        yield ReasonCode.CONTROLLER_MODE_MISMATCH
    if _differs(offer.calibration_epoch, hello.calibration_epoch):
        yield ReasonCode.CALIBRATION_MISMATCH
    if offer.queue_epoch is not None and offer.queue_epoch < hello.queue_epoch:
        yield ReasonCode.OLD_QUEUE_EPOCH
    if offer.queue_epoch is not None and offer.queue_epoch > hello.queue_epoch:
        yield ReasonCode.FUTURE_QUEUE_EPOCH
    if offer.reason_codes is not None and not all(is_known(c) for c in offer.reason_codes):
        yield ReasonCode.PROTOCOL_MISMATCH


def _differs(offered: object, own: object) -> bool:
    return offered is not None and str(offered) != str(own)


def _common_protocol(ours: tuple[int, int], theirs: tuple[int, int]) -> int | None:
    low, high = max(ours[0], theirs[0]), min(ours[1], theirs[1])
    if theirs[0] > theirs[1] or low > high:
        return None
    return high


def fingerprint(hello: ClientHello, offer: HandshakeOffer, protocol: int) -> str:
    """BLAKE2b-128 over the agreed fields, in a fixed order; both sides compute the same."""
    agreed = [
        protocol, offer.policy_checkpoint, offer.config_hash, list(hello.observation_keys),
        hello.action_dim, hello.action_units, hello.action_frame, offer.chunk_horizon,
        hello.skill, hello.skill_version, hello.controller_mode, hello.control_rate_hz,
        str(hello.calibration_epoch), hello.queue_epoch,
    ]
    return hashlib.blake2b(msgspec.msgpack.encode(agreed), digest_size=16).hexdigest()
