"""The ``session`` and ``allowlist`` sections: this client's side of the handshake, the start
state, and the (checkpoint, configuration) tuples a deployment accepts."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from assurance.handshake import Session
from assurance.limits import JointLimits
from kernel.core.config import ClientSide
from kernel.scenario.bounds import PROTOCOL_MAX, QUEUE_EPOCH_MAX
from kernel.scenario.fields import Where, choice, integer, text, vector
from skills.phases import TaskPhase

INITIAL_FINGERPRINT = "scenario-session"


def session_section(
    doc: Mapping[str, Any], where: Where, limits: JointLimits, period_ms: float
) -> tuple[ClientSide, Session, TaskPhase, np.ndarray, int]:
    """The client side, the accepted session, the start phase, the start state and the queue
    epoch.

    Raises:
        ScenarioError: naming the key, for anything missing or out of its bounds (the start
            state outside the position limits included).
    """
    low, high = _protocol(doc, where)
    keys = doc.get("observation_keys", [])
    if not isinstance(keys, list) or not all(isinstance(k, str) for k in keys):
        raise where.at("observation_keys").error("must be a list of strings")
    client = ClientSide(
        skill=text(doc, "skill", where, default="skill"),
        skill_version=text(doc, "skill_version", where),
        observation_keys=tuple(keys),
        action_dim=integer(doc, "action_dim", where, default=limits.dim, minimum=1),
        action_units=text(doc, "action_units", where, default="rad"),
        action_frame=text(doc, "action_frame", where, default="joint"),
        controller_mode=text(doc, "controller_mode", where),
        calibration_epoch=text(doc, "calibration_epoch", where),
        protocol=(low, high),
        control_rate_hz=1000.0 / period_ms,
    )
    session = Session(text(doc, "policy_checkpoint", where), text(doc, "config_hash", where),
                      INITIAL_FINGERPRINT, high, 1)
    phase = TaskPhase(choice(doc, "phase", where, tuple(TaskPhase)))
    q0 = _initial_state(doc, where, limits)
    epoch = integer(doc, "queue_epoch", where, 0, minimum=0, maximum=QUEUE_EPOCH_MAX)
    return client, session, phase, q0, epoch


def _protocol(doc: Mapping[str, Any], where: Where) -> tuple[int, int]:
    here = where.at("protocol")
    version = vector(doc.get("protocol", [1, 1]), here, 2, bound=PROTOCOL_MAX)
    if version[0] > version[1] or version[0] < 1 or not all(v.is_integer() for v in version):
        raise here.error(f"must be [min, max] integer versions with 1 <= min <= max <= "
                         f"{PROTOCOL_MAX}")
    return int(version[0]), int(version[1])


def _initial_state(doc: Mapping[str, Any], where: Where, limits: JointLimits) -> np.ndarray:
    if "state" not in doc:
        raise where.error("missing required key 'state'")
    raw = doc["state"]
    here = where.at("state")
    if isinstance(raw, dict):
        raw, here = raw.get("q"), here.at("q")
    q0 = state_vector(raw, here, limits)
    outside = np.flatnonzero((q0 < limits.lower) | (q0 > limits.upper))
    if outside.size:
        index = int(outside[0])
        raise here.at(index).error(
            f"{q0[index]:g} is outside the position limits [{limits.lower[index]:g}, "
            f"{limits.upper[index]:g}]: the core would start from a state the robot cannot be in")
    return q0


def state_vector(raw: Any, where: Where, limits: JointLimits, finite: bool = True) -> np.ndarray:
    q = vector(raw, where, finite=finite)
    grip = limits.gripper_index
    if len(q) == limits.dim - 1 and grip is not None:
        q = [*q[:grip], 0.0, *q[grip:]]
    if len(q) != limits.dim:
        raise where.error(f"has {len(q)} values, the robot has {limits.dim} dimensions")
    return np.array(q)


def allowlist_section(
    doc: Mapping[str, Any], where: Where, session: Session
) -> frozenset[tuple[str, str]]:
    if "allowlist" not in doc:
        return frozenset({(session.policy_checkpoint, session.config_hash)})
    raw = doc["allowlist"]
    here = where.at("allowlist")
    if not isinstance(raw, list):
        raise here.error("must be a list of {policy_checkpoint, config_hash}")
    entries = set()
    for index, entry in enumerate(raw):
        if not isinstance(entry, dict):
            raise here.at(index).error("must be an object")
        entries.add((text(entry, "policy_checkpoint", here.at(index)),
                     text(entry, "config_hash", here.at(index))))
    return frozenset(entries)
