"""The non-event parts of a scenario: robot, timing, phases, session, allowlist, motion →
CoreConfig.

These sections fail closed (docs/contract.md §7): an unknown key in ``robot``, ``timing``,
``phases`` (or a phase card), ``session`` or ``motion`` is an error naming the key, so a
misspelled limit or threshold can never silently mean its default; every arm joint needs a
finite position, velocity and acceleration limit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from assurance.clock import ms_to_ns
from assurance.handshake import Session
from assurance.limits import JointLimits
from assurance.policy import ForceBand, LinkLoss, PhasePolicy
from assurance.watermarks import WatermarkConfig
from kernel.core.config import ClientSide, CoreConfig, MotionConfig
from kernel.scenario.fields import (
    ScenarioError,
    Where,
    choice,
    flag,
    integer,
    is_number,
    mapping,
    number,
    text,
    vector,
)
from kernel.scenario.kinematics import cartesian_mapper, robot_kinematics
from skills.phases import Executor, PhaseBook, PhaseCard, TaskPhase

INITIAL_FINGERPRINT = "scenario-session"

SECTION_KEYS: dict[str, frozenset[str]] = {
    "robot": frozenset({"dof", "position_limits", "velocity_limits", "acceleration_limits",
                        "gripper_index", "gripper_event_threshold", "kinematics", "model",
                        "tcp_frame", "joints", "model_sha256", "workspace"}),
    "timing": frozenset({"control_period_ms", "clock_uncertainty_ms", "degrade_after",
                         "state_timeout_ms", "low_watermark_ms", "high_watermark_ms",
                         "request_retry_ms"}),
    "session": frozenset({"queue_epoch", "skill", "skill_version", "policy_checkpoint",
                          "config_hash", "controller_mode", "calibration_epoch",
                          "observation_keys", "action_dim", "action_units", "action_frame",
                          "protocol", "phase", "state"}),
    "motion": frozenset({"interpolator_jerk", "planner_velocity", "planner_acceleration",
                         "planner_jerk", "impedance"}),
}
"""The keys each fail-closed section may hold (``phases`` is checked per card)."""
PHASE_KEYS = frozenset({"max_observation_age_ms", "max_action_age_ms", "max_divergence",
                        "max_projection", "trim", "blend", "force_band", "ood_threshold",
                        "controller_mode", "max_underrun_ms", "executor", "proposals",
                        "link_loss", "link_loss_hold_factor"})


def check_keys(doc: Mapping[str, Any], where: Where) -> None:
    """Refuse any key a fail-closed section does not define, naming it."""
    for section, known in SECTION_KEYS.items():
        if isinstance(doc.get(section), dict):
            _known_only(doc[section], known, where.at(section))
    phases = doc.get("phases")
    if isinstance(phases, dict):
        for name, card in phases.items():
            if isinstance(card, dict):
                _known_only(card, PHASE_KEYS, where.at("phases").at(name))


def _known_only(table: Mapping[str, Any], known: frozenset[str], where: Where) -> None:
    for key in table:
        if key not in known:
            raise where.at(key).error(f"unknown key (known: {', '.join(sorted(known))})")


def build_config(doc: Mapping[str, Any], where: Where) -> CoreConfig:
    check_keys(doc, where)
    robot = mapping(doc, "robot", where)
    limits = robot_limits(robot, where.at("robot"))
    kinematics = robot_kinematics(robot, where.at("robot"), limits)
    timing = mapping(doc, "timing", where, required=False)
    period = number(timing, "control_period_ms", where.at("timing"), default=2.0, positive=True)
    if ms_to_ns(period) <= 0:
        raise where.at("timing").at("control_period_ms").error(
            f"must be at least 1 ns (0.000001 ms), got {period!r}")
    uncertainty = number(timing, "clock_uncertainty_ms", where.at("timing"), 0.0, minimum=0)
    session_doc = mapping(doc, "session", where)
    client, session, phase, q0, epoch = _session(session_doc, where.at("session"), limits, period)
    cartesian = cartesian_mapper(doc, where, limits, client, kinematics)
    if cartesian is None and client.action_dim != limits.dim:
        raise where.at("session").at("action_dim").error(
            f"must be {limits.dim}, one per robot dimension, for joint-space actions, "
            f"got {client.action_dim}")
    return CoreConfig(
        limits=limits, control_period_ns=ms_to_ns(period),
        clock_uncertainty_ns=ms_to_ns(uncertainty),
        phases=_phases(mapping(doc, "phases", where, required=False), where.at("phases")),
        client=client, allowlist=_allowlist(doc, where, session),
        initial_session=session, initial_phase=phase, initial_q=q0, initial_epoch=epoch,
        watermarks=_watermarks(timing, where.at("timing")),
        degrade_after=integer(timing, "degrade_after", where.at("timing"), 3, minimum=1),
        state_timeout_ns=_optional_ms(timing, "state_timeout_ms", where.at("timing")),
        cartesian=cartesian, kinematics=kinematics,
        motion=motion_config(mapping(doc, "motion", where, required=False), where.at("motion")),
    )


def motion_config(doc: Mapping[str, Any], where: Where) -> MotionConfig:
    default = MotionConfig()
    return MotionConfig(
        interpolator_jerk=number(doc, "interpolator_jerk", where, default.interpolator_jerk,
                                 positive=True),
        planner_velocity=number(doc, "planner_velocity", where, default.planner_velocity,
                                positive=True),
        planner_acceleration=number(doc, "planner_acceleration", where,
                                    default.planner_acceleration, positive=True),
        planner_jerk=number(doc, "planner_jerk", where, default.planner_jerk, positive=True),
        impedance=flag(doc, "impedance", where, default.impedance),
    )


# -- robot --------------------------------------------------------------------------------------


def robot_limits(robot: Mapping[str, Any], where: Where) -> JointLimits:
    dof = integer(robot, "dof", where, minimum=1)
    grip = robot.get("gripper_index")
    if grip is not None:
        grip = integer(robot, "gripper_index", where, minimum=0)
        if grip > dof:
            raise where.at("gripper_index").error(f"must be at most dof ({dof}), got {grip}")
    dim = dof + 1 if grip == dof else dof
    lower, upper = _position_limits(robot, where, dim, grip)
    velocity = _rate_limits(robot, "velocity_limits", where, dim, grip)
    acceleration = _rate_limits(robot, "acceleration_limits", where, dim, grip)
    try:
        return JointLimits(
            lower, upper, velocity, acceleration, gripper_index=grip,
            gripper_event_threshold=number(robot, "gripper_event_threshold", where, 1e-3,
                                           minimum=0),
        )
    except ValueError as error:
        raise where.error(str(error)) from None


def _pad_gripper(values: list[float], dim: int, grip: int | None, fill: float) -> list[float]:
    if len(values) == dim - 1 and grip is not None:
        return [*values[:grip], fill, *values[grip:]]
    return values


def _position_limits(
    robot: Mapping[str, Any], where: Where, dim: int, grip: int | None
) -> tuple[np.ndarray, np.ndarray]:
    here = where.at("position_limits")
    raw = robot.get("position_limits")
    if raw is None:
        raise where.error("missing required key 'position_limits' (every joint needs one: "
                          "a limit never defaults to unbounded)")
    if is_number(raw):
        bound = abs(float(raw))
        return np.full(dim, -bound), np.full(dim, bound)
    if isinstance(raw, dict):
        low_key = "lower" if "lower" in raw else "min"
        high_key = "upper" if "upper" in raw else "max"
        lower = vector(raw.get(low_key), here.at(low_key))
        upper = vector(raw.get(high_key), here.at(high_key))
    elif isinstance(raw, list) and all(isinstance(p, list) and len(p) == 2 for p in raw) and (
        len(raw) in (dim, dim - 1)
    ):
        pairs = [vector(p, here.at(i), 2) for i, p in enumerate(raw)]
        lower, upper = [p[0] for p in pairs], [p[1] for p in pairs]
    else:
        raise here.error("must be a list of [lower, upper] pairs, {lower, upper}, or a number")
    lower = _pad_gripper(lower, dim, grip, -math.inf)
    upper = _pad_gripper(upper, dim, grip, math.inf)
    if len(lower) != dim or len(upper) != dim:
        raise here.error(f"has {len(lower)} entries, the robot has {dim} dimensions")
    for index, (low, high) in enumerate(zip(lower, upper, strict=True)):
        if low > high:
            raise here.at(index).error(f"lower limit {low} exceeds upper limit {high}")
    return np.array(lower), np.array(upper)


def _rate_limits(
    robot: Mapping[str, Any], key: str, where: Where, dim: int, grip: int | None
) -> np.ndarray:
    raw = robot.get(key)
    here = where.at(key)
    if raw is None:
        raise where.error(f"missing required key {key!r} (every joint needs one: a limit "
                          "never defaults to unbounded)")
    if is_number(raw):
        values = [float(raw)] * dim
    else:
        values = _pad_gripper(vector(raw, here), dim, grip, math.inf)
    if len(values) != dim:
        raise here.error(f"has {len(values)} entries, the robot has {dim} dimensions")
    if any(v <= 0 for v in values):
        raise here.error("must be positive")
    return np.array(values)


# -- phases -------------------------------------------------------------------------------------


def _phases(doc: Mapping[str, Any], where: Where) -> PhaseBook:
    cards: dict[TaskPhase, PhaseCard] = {}
    for name, body in doc.items():
        here = where.at(name)
        if name not in TaskPhase.__members__:
            raise here.error(f"unknown phase {name!r} (expected one of {', '.join(TaskPhase)})")
        if not isinstance(body, dict):
            raise here.error("must be an object")
        phase = TaskPhase(name)
        executor = body.get("executor")
        if executor is not None:
            executor = Executor(choice(body, "executor", here, tuple(Executor)))
        proposals = flag(body, "proposals", here, True) if "proposals" in body else None
        cards[phase] = PhaseBook.make_card(phase, phase_policy(body, here), executor, proposals)
    return PhaseBook(cards)


def phase_policy(body: Mapping[str, Any], where: Where) -> PhasePolicy:
    default = PhasePolicy()
    return PhasePolicy(
        max_observation_age_ns=_ms(body, "max_observation_age_ms", where,
                                   default.max_observation_age_ns),
        max_action_age_ns=_ms(body, "max_action_age_ms", where, default.max_action_age_ns),
        max_divergence=number(body, "max_divergence", where, default.max_divergence, minimum=0),
        max_projection=number(body, "max_projection", where, default.max_projection, minimum=0),
        trim=flag(body, "trim", where, default.trim),
        blend=flag(body, "blend", where, default.blend),
        force_band=_force_band(body.get("force_band"), where.at("force_band")),
        ood_threshold=(number(body, "ood_threshold", where) if body.get("ood_threshold")
                       is not None else None),
        controller_mode=(text(body, "controller_mode", where) if body.get("controller_mode")
                         is not None else None),
        max_underrun_ns=_optional_ms(body, "max_underrun_ms", where),
        link_loss=LinkLoss(choice(body, "link_loss", where, tuple(LinkLoss),
                                  default.link_loss)),
        link_loss_hold_factor=_fraction(body, "link_loss_hold_factor", where,
                                        default.link_loss_hold_factor),
    )


def _fraction(body: Mapping[str, Any], key: str, where: Where, default: float) -> float:
    value = number(body, key, where, default, positive=True)
    if value > 1:
        raise where.at(key).error(f"must be at most 1 (a fraction), got {value!r}")
    return value


def _ms(body: Mapping[str, Any], key: str, where: Where, default_ns: int) -> int:
    if body.get(key) is None:
        return default_ns
    return ms_to_ns(number(body, key, where, minimum=0))


def _optional_ms(body: Mapping[str, Any], key: str, where: Where) -> int | None:
    if body.get(key) is None:
        return None
    value = number(body, key, where, positive=True)
    if ms_to_ns(value) <= 0:
        raise where.at(key).error(f"must be at least 1 ns (0.000001 ms), got {value!r}")
    return ms_to_ns(value)


def _force_band(raw: Any, where: Where) -> ForceBand | None:
    if raw is None:
        return None
    if is_number(raw) and math.isfinite(raw) and raw >= 0:
        return ForceBand(-float(raw), float(raw))
    if isinstance(raw, list) and len(raw) == 2:
        low, high = vector(raw, where, 2)
        if low <= high:
            return ForceBand(low, high)
    if isinstance(raw, dict):
        low, high = number(raw, "low", where), number(raw, "high", where)
        if low <= high:
            return ForceBand(low, high)
    raise where.error("must be a non-negative number, [low, high] or {low, high}")


# -- session ------------------------------------------------------------------------------------


def _session(
    doc: Mapping[str, Any], where: Where, limits: JointLimits, period_ms: float
) -> tuple[ClientSide, Session, TaskPhase, np.ndarray, int]:
    protocol = doc.get("protocol", [1, 1])
    version = vector(protocol, where.at("protocol"), 2)
    if version[0] > version[1] or not all(float(v).is_integer() for v in version):
        raise where.at("protocol").error("must be [min, max] integer versions with min <= max")
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
        protocol=(int(version[0]), int(version[1])),
        control_rate_hz=1000.0 / period_ms,
    )
    session = Session(text(doc, "policy_checkpoint", where), text(doc, "config_hash", where),
                      INITIAL_FINGERPRINT, int(version[1]), 1)
    phase = TaskPhase(choice(doc, "phase", where, tuple(TaskPhase)))
    q0 = _initial_state(doc, where, limits)
    return client, session, phase, q0, integer(doc, "queue_epoch", where, 0, minimum=0)


def _initial_state(doc: Mapping[str, Any], where: Where, limits: JointLimits) -> np.ndarray:
    if "state" not in doc:
        raise where.error("missing required key 'state'")
    raw = doc["state"]
    here = where.at("state")
    if isinstance(raw, dict):
        raw, here = raw.get("q"), here.at("q")
    return state_vector(raw, here, limits)


def state_vector(raw: Any, where: Where, limits: JointLimits, finite: bool = True) -> np.ndarray:
    q = vector(raw, where, finite=finite)
    grip = limits.gripper_index
    if len(q) == limits.dim - 1 and grip is not None:
        q = [*q[:grip], 0.0, *q[grip:]]
    if len(q) != limits.dim:
        raise where.error(f"has {len(q)} values, the robot has {limits.dim} dimensions")
    return np.array(q)


def _allowlist(
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


def _watermarks(timing: Mapping[str, Any], where: Where) -> WatermarkConfig:
    default = WatermarkConfig()
    try:
        return WatermarkConfig(
            low_ns=_ms(timing, "low_watermark_ms", where, default.low_ns),
            high_ns=_ms(timing, "high_watermark_ms", where, default.high_ns),
            retry_ns=_ms(timing, "request_retry_ms", where, default.retry_ns),
        )
    except ValueError as error:
        raise where.error(str(error)) from None


__all__ = ["ScenarioError", "build_config", "phase_policy", "robot_limits", "state_vector"]
