"""Building blocks for scenario files: a standard cell, chunks, states, and matchers."""

from __future__ import annotations

import copy
import json
import math
from dataclasses import dataclass, field
from typing import Any

Q0 = [0.0, -1.2, 1.5, -1.87, -1.57, 0.0]
DELTA = [0.002, -0.003, 0.004, -0.001, 0.0, 0.001]
OBS_KEYS = ["wrist_rgb", "scene_rgb", "joint_pos", "wrench"]
IDENTITY = {
    "policy_checkpoint": "act-insert-2026-07",
    "config_hash": "cfg-9f2c",
    "skill_version": "3.1.0",
    "controller_mode": "joint_position",
    "calibration_epoch": "cal-12",
}
EVIDENCE = {
    "pose_within_tolerance": True, "controller_mode_ack": True, "force_fresh": True,
    "contact_envelope_valid": True,
}


def q_at(k: float, base: list[float] | None = None) -> list[float]:
    """The approach path: ``k`` steps of DELTA from ``base`` (Q0 by default)."""
    start = base or Q0
    return [round(a + k * b, 6) for a, b in zip(start, DELTA, strict=True)]


def ramp(first: int, count: int, base: list[float] | None = None) -> list[list[float]]:
    return [q_at(first + j, base) for j in range(count)]


def robot(gripper: bool = False) -> dict[str, Any]:
    dof = 6
    doc: dict[str, Any] = {
        "dof": dof,
        "position_limits": [[-6.28, 6.28], [-6.28, 6.28], [-3.14, 3.14], [-6.28, 6.28],
                            [-6.28, 6.28], [-6.28, 6.28]],
        "velocity_limits": [3.14] * dof,
        "acceleration_limits": [40.0] * dof,
    }
    if gripper:
        doc["gripper_index"] = dof
    return doc


def phases() -> dict[str, Any]:
    return {
        "FREE_SPACE": {"max_observation_age_ms": 80, "max_action_age_ms": 200,
                       "max_divergence": 0.05, "max_projection": 0.02, "trim": True,
                       "blend": True},
        "PRE_CONTACT": {"max_observation_age_ms": 60, "max_action_age_ms": 120,
                        "max_divergence": 0.02, "max_projection": 0.01, "trim": False,
                        "blend": False, "ood_threshold": 0.8},
        "CONTACT": {"max_observation_age_ms": 40, "max_action_age_ms": 150,
                    "max_divergence": 0.005, "max_projection": 0.005, "trim": False,
                    "blend": False, "force_band": 15.0},
    }


def session(phase: str = "PRE_CONTACT", epoch: int = 0, state: list[float] | None = None,
            action_dim: int = 6) -> dict[str, Any]:
    return {
        "queue_epoch": epoch, "skill": "peg_insert", **IDENTITY,
        "observation_keys": list(OBS_KEYS), "action_dim": action_dim, "action_units": "rad",
        "action_frame": "joint", "protocol": [1, 2], "phase": phase,
        "state": state or list(Q0),
    }


def offer(**changes: Any) -> dict[str, Any]:
    """A compatible server offer; keyword arguments change one field at a time."""
    doc = {
        "policy_checkpoint": IDENTITY["policy_checkpoint"],
        "config_hash": IDENTITY["config_hash"], "observation_keys": list(OBS_KEYS),
        "action_dim": 6, "action_units": "rad", "action_frame": "joint", "chunk_horizon": 10,
        "protocol": [1, 2], "skill": "peg_insert", "skill_version": IDENTITY["skill_version"],
        "controller_mode": IDENTITY["controller_mode"],
        "calibration_epoch": IDENTITY["calibration_epoch"],
    }
    doc.update(changes)
    return doc


def chunk(
    t: float, chunk_id: str, sequence: int, observation: str, obs_t: float, first: float,
    actions: list[list[float]], phase: str = "PRE_CONTACT", epoch: int = 0, dt: float = 10,
    **fields: Any,
) -> dict[str, Any]:
    """A well-formed chunk event; ``fields`` override any envelope field."""
    rows = actions if isinstance(actions, list) else []
    first_row = rows[0] if rows and isinstance(rows[0], list) else []
    doc = {
        "t": t, "kind": "chunk", "chunk_id": chunk_id, "sequence": sequence,
        "queue_epoch": epoch, **IDENTITY, "task_phase": phase, "observation_id": observation,
        "observation_event_time": obs_t, "observation_arrival_time": obs_t + 1,
        "clock_domain": "client", "inference_start": obs_t + 5,
        "inference_end": max(obs_t + 6, t - 4), "server_send": max(obs_t + 7, t - 3),
        "first_action_time": first, "action_dt": dt,
        "last_action_time": first + (len(rows) - 1) * dt if rows else DROP,
        "max_observation_age": 60, "max_action_age": 150,
        "state_fingerprint": {"q": first_row, "hash": ""},
        "replacement_policy": "replace", "fallback_id": "staging_retreat",
        "actions": actions,
    }
    doc.update(fields)
    return {k: v for k, v in doc.items() if v is not _DROP}


_DROP = object()
DROP = _DROP
"""Pass ``field=DROP`` to :func:`chunk` to leave a field out."""


def state(t: float, q: list[float], **fields: Any) -> dict[str, Any]:
    return {"t": t, "kind": "state", "q": q, **fields}


def observation(t: float, observation_id: str) -> dict[str, Any]:
    return {"t": t, "kind": "observation", "observation_id": observation_id}


def event(t: float, kind: str, **fields: Any) -> dict[str, Any]:
    return {"t": t, "kind": kind, **fields}


@dataclass
class ScenarioSpec:
    name: str
    description: str
    events: list[dict[str, Any]]
    until: float
    expect: list[dict[str, Any]]
    forbid: list[dict[str, Any]] = field(default_factory=list)
    phase: str = "PRE_CONTACT"
    epoch: int = 0
    gripper: bool = False
    timing: dict[str, Any] = field(default_factory=dict)
    phases: dict[str, Any] | None = None
    session: dict[str, Any] | None = None
    robot: dict[str, Any] | None = None
    geometry: dict[str, Any] | None = None
    """The cell's ``geometry`` section, for the scenarios that check clearances."""
    cameras: list[dict[str, Any]] | None = None
    """The ``cameras`` section, for the scenarios that lose one."""

    def document(self) -> dict[str, Any]:
        timing = {"control_period_ms": 2, "clock_uncertainty_ms": 1, **self.timing}
        return {
            "format": "warden-scenario/1",
            "name": self.name,
            "description": self.description,
            "robot": self.robot or robot(self.gripper),
            "timing": timing,
            "phases": self.phases if self.phases is not None else phases(),
            "session": self.session or session(self.phase, self.epoch,
                                               action_dim=7 if self.gripper else 6),
            "allowlist": [{"policy_checkpoint": IDENTITY["policy_checkpoint"],
                           "config_hash": IDENTITY["config_hash"]},
                          {"policy_checkpoint": "act-insert-2026-06", "config_hash": "cfg-77a1"}],
            **({"geometry": self.geometry} if self.geometry is not None else {}),
            **({"cameras": self.cameras} if self.cameras is not None else {}),
            "events": sorted(copy.deepcopy(self.events), key=lambda e: e["t"]),
            "until": self.until,
            "expect": self.expect,
            "forbid": self.forbid,
        }


def dumps(doc: dict[str, Any]) -> str:
    """JSON with one line per event and per action row, NaN/Infinity as Python writes them."""
    return _format(doc, 0) + "\n"


def _format(value: Any, depth: int) -> str:
    pad, inner = "  " * depth, "  " * (depth + 1)
    if isinstance(value, dict) and depth < 2 and value:
        body = ",\n".join(f"{inner}{json.dumps(k)}: {_format(v, depth + 1)}"
                          for k, v in value.items())
        return "{\n" + body + "\n" + pad + "}"
    if isinstance(value, list) and depth < 2 and value and all(
            isinstance(v, dict) for v in value):
        body = ",\n".join(f"{inner}{_compact(v)}" for v in value)
        return "[\n" + body + "\n" + pad + "]"
    return _compact(value)


def _compact(value: Any) -> str:
    return json.dumps(value, separators=(", ", ": "), allow_nan=True)


def nan() -> float:
    return math.nan
