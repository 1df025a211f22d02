"""The compatibility handshake (docs/contract.md §5)."""

from __future__ import annotations

from typing import Any

import msgspec
import pytest

from assurance.handshake import (
    ClientHello,
    HandshakeOffer,
    decode_offer,
    evaluate,
    fingerprint,
)
from assurance.reasons import ReasonCode as R

HELLO = ClientHello(
    skill="insert", skill_version="1.2", observation_keys=("cam", "q", "force"), action_dim=7,
    action_units="rad", action_frame="joint", controller_mode="position", control_rate_hz=500.0,
    calibration_epoch="3", queue_epoch=4, protocol=(1, 3), reason_codes=tuple(R),
)
OFFER: dict[str, Any] = {
    "policy_checkpoint": "act-2024-05", "config_hash": "cfg-a", "observation_keys": ["cam", "q",
    "force"], "action_dim": 7, "action_units": "rad", "action_frame": "joint",
    "chunk_horizon": 20, "protocol": [2, 5], "skill": "insert", "skill_version": "1.2",
    "controller_mode": "position", "calibration_epoch": 3, "queue_epoch": 4,
    "reason_codes": ["MALFORMED", "EXPIRED"],
}
ALLOW = frozenset({("act-2024-05", "cfg-a")})


def offer(**changes: Any) -> dict[str, Any]:
    return {**OFFER, **changes}


def reasons_for(**changes: Any) -> tuple[str, ...]:
    decision, session = evaluate(HELLO, offer(**changes), ALLOW)
    assert decision.decision == "REJECT" and session is None and decision.fingerprint is None
    return decision.reasons


def test_compatible_offer_is_accepted_with_a_fingerprint() -> None:
    decision, session = evaluate(HELLO, offer(), ALLOW)
    assert decision.decision == "ACCEPT" and decision.reasons == ()
    assert decision.protocol == 3  # the highest common version
    assert session is not None and session.fingerprint == decision.fingerprint
    assert (session.policy_checkpoint, session.config_hash) == ("act-2024-05", "cfg-a")
    assert session.chunk_horizon == 20 and session.protocol == 3
    assert len(decision.fingerprint) == 32


def test_optional_server_fields_may_be_omitted() -> None:
    minimal = {k: OFFER[k] for k in ("policy_checkpoint", "config_hash", "observation_keys",
                                     "action_dim", "action_units", "action_frame",
                                     "chunk_horizon", "protocol")}
    assert evaluate(HELLO, minimal, ALLOW)[0].decision == "ACCEPT"


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({"policy_checkpoint": "act-2023-11"}, R.CHECKPOINT_NOT_ALLOWED),
        ({"config_hash": "cfg-old"}, R.CHECKPOINT_NOT_ALLOWED),
        ({"observation_keys": ["q", "cam", "force"]}, R.SCHEMA_MISMATCH),
        ({"calibration_epoch": 2}, R.CALIBRATION_MISMATCH),
        ({"action_units": "deg"}, R.SCHEMA_MISMATCH),
        ({"action_dim": 6}, R.SCHEMA_MISMATCH),
        ({"action_frame": "base"}, R.SCHEMA_MISMATCH),
        ({"controller_mode": "torque"}, R.CONTROLLER_MODE_MISMATCH),
        ({"skill_version": "1.1"}, R.SKILL_MISMATCH),
        ({"reason_codes": ["MALFORMED", "SERVER_SAYS_NO"]}, R.PROTOCOL_MISMATCH),
        ({"queue_epoch": 0}, R.OLD_QUEUE_EPOCH),
        ({"queue_epoch": 9}, R.FUTURE_QUEUE_EPOCH),
        ({"protocol": [4, 6]}, R.PROTOCOL_MISMATCH),
        ({"protocol": [3, 2]}, R.PROTOCOL_MISMATCH),
        ({"chunk_horizon": 0}, R.MALFORMED),
    ],
    ids=["old-checkpoint", "old-config", "reordered-keys", "stale-calibration", "wrong-unit",
         "wrong-dim", "wrong-frame", "unsupported-mode", "old-skill", "unknown-reason-code",
         "server-restart-old-epoch", "future-epoch", "no-common-protocol", "inverted-range",
         "zero-horizon"],
)
def test_seed_matrix_rejections(changes: dict[str, Any], reason: R) -> None:
    assert reasons_for(**changes) == (reason,)


@pytest.mark.parametrize("missing", ["policy_checkpoint", "observation_keys", "protocol",
                                     "chunk_horizon"])
def test_missing_required_field_is_malformed(missing: str) -> None:
    bad = offer()
    del bad[missing]
    assert reasons_for_offer(bad) == (R.MALFORMED,)


@pytest.mark.parametrize("bad", [None, [], "ACCEPT", {"protocol": "1"}])
def test_an_offer_that_is_not_an_offer_is_malformed(bad: Any) -> None:
    assert isinstance(decode_offer(bad), str)
    assert reasons_for_offer(bad) == (R.MALFORMED,)


def reasons_for_offer(raw: Any) -> tuple[str, ...]:
    decision, session = evaluate(HELLO, raw, ALLOW)
    assert decision.decision == "REJECT" and session is None
    return decision.reasons


def test_a_rejection_lists_every_reason_in_canonical_order() -> None:
    reasons = reasons_for(policy_checkpoint="old", observation_keys=["q"], calibration_epoch=1,
                          controller_mode="torque", queue_epoch=1, protocol=[7, 9])
    assert reasons == (R.SCHEMA_MISMATCH, R.OLD_QUEUE_EPOCH, R.PROTOCOL_MISMATCH,
                       R.CHECKPOINT_NOT_ALLOWED, R.CONTROLLER_MODE_MISMATCH,
                       R.CALIBRATION_MISMATCH)


def test_protocol_mismatch_is_listed_once_for_two_causes() -> None:
    assert reasons_for(protocol=[7, 9], reason_codes=["NOPE"]) == (R.PROTOCOL_MISMATCH,)


def test_typed_offer_is_accepted_as_is() -> None:
    typed = decode_offer(offer())
    assert isinstance(typed, HandshakeOffer)
    assert evaluate(HELLO, typed, ALLOW)[0] == evaluate(HELLO, offer(), ALLOW)[0]


# --- fingerprint -------------------------------------------------------------------------------


def accepted_print(hello: ClientHello = HELLO, **changes: Any) -> str:
    decision, _ = evaluate(hello, offer(**changes), ALLOW | {("ck2", "cfg-a"), ("act-2024-05",
                                                                                  "cfg2")})
    assert decision.decision == "ACCEPT", decision
    return decision.fingerprint


def test_fingerprint_is_deterministic() -> None:
    typed = decode_offer(offer())
    assert fingerprint(HELLO, typed, 3) == fingerprint(HELLO, typed, 3) == accepted_print()


@pytest.mark.parametrize(
    "changes",
    [{"policy_checkpoint": "ck2"}, {"config_hash": "cfg2"}, {"chunk_horizon": 21},
     {"protocol": [1, 2]}],
)
def test_fingerprint_changes_with_any_offered_agreed_field(changes: dict[str, Any]) -> None:
    assert accepted_print(**changes) != accepted_print()


HELLO_CHANGES = {
    "skill": "peg", "skill_version": "2.0", "observation_keys": ("q", "cam", "force"),
    "action_dim": 6, "action_units": "deg", "action_frame": "tool", "controller_mode": "torque",
    "control_rate_hz": 250.0, "calibration_epoch": "9", "queue_epoch": 5,
}


@pytest.mark.parametrize("name", sorted(HELLO_CHANGES))
def test_fingerprint_changes_with_any_agreed_client_field(name: str) -> None:
    changed = msgspec.structs.replace(HELLO, **{name: HELLO_CHANGES[name]})
    typed = decode_offer(offer())
    assert fingerprint(changed, typed, 3) != fingerprint(HELLO, typed, 3)
