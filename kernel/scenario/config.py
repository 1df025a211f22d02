"""The non-event parts of a scenario: robot, timing, phases, session, allowlist, motion →
CoreConfig.

These sections fail closed (docs/contract.md, "Reading a scenario"): an unknown key in
``robot``, ``timing``, ``phases`` (or a phase card), ``session`` or ``motion`` is an error naming
the key, so a misspelled limit or threshold can never silently mean its default; every arm joint
needs a finite position, velocity and acceleration limit; and every limit and threshold lies
within the physical bounds of :mod:`kernel.scenario.bounds`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from assurance.clock import ms_to_ns
from assurance.limits import JointLimits
from assurance.policy import ForceBand, LinkLoss, PhasePolicy
from assurance.watermarks import WatermarkConfig
from kernel.core.config import CoreConfig, MotionConfig, TrialBounds
from kernel.scenario.bounds import (
    ACCELERATION_LIMIT_MAX,
    DEGRADE_AFTER_MAX,
    DOF_MAX,
    DURATION_MAX_MS,
    FORCE_MAX_N,
    JERK_MAX,
    PERIOD_MAX_MS,
    PERIOD_MIN_MS,
    POSITION_LIMIT_MAX,
    UNCERTAINTY_MAX_MS,
    VELOCITY_LIMIT_MAX,
)
from kernel.scenario.fields import (
    ScenarioError,
    Where,
    choice,
    flag,
    in_range,
    integer,
    is_number,
    mapping,
    number,
    text,
    vector,
)
from kernel.scenario.kinematics import cartesian_mapper, robot_kinematics
from kernel.scenario.session import allowlist_section, session_section, state_vector
from kernel.scenario.trial import trial_bounds
from skills.phases import Executor, PhaseBook, PhaseCard, TaskPhase

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
    "envelope": frozenset({"workspace", "max_wrist_force_n"}),
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


def build_config(doc: Mapping[str, Any], where: Where,
                 envelope: TrialBounds | None = None) -> CoreConfig:
    """The core's configuration from a scenario's sections; ``envelope``: a live trial's,
    typed (``doc`` then has no ``envelope`` section)."""
    check_keys(doc, where)
    robot = mapping(doc, "robot", where)
    limits = robot_limits(robot, where.at("robot"))
    kinematics = robot_kinematics(robot, where.at("robot"), limits)
    timing = mapping(doc, "timing", where, required=False)
    period = number(timing, "control_period_ms", where.at("timing"), default=2.0,
                    minimum=PERIOD_MIN_MS, maximum=PERIOD_MAX_MS)
    uncertainty = number(timing, "clock_uncertainty_ms", where.at("timing"), 0.0, minimum=0,
                         maximum=UNCERTAINTY_MAX_MS)
    session_doc = mapping(doc, "session", where)
    client, session, phase, q0, epoch = session_section(session_doc, where.at("session"),
                                                        limits, period)
    cartesian = cartesian_mapper(doc, where, limits, client, kinematics)
    if cartesian is None and client.action_dim != limits.dim:
        raise where.at("session").at("action_dim").error(
            f"must be {limits.dim}, one per robot dimension, for joint-space actions, "
            f"got {client.action_dim}")
    return CoreConfig(
        limits=limits, control_period_ns=ms_to_ns(period),
        clock_uncertainty_ns=ms_to_ns(uncertainty),
        phases=_phases(mapping(doc, "phases", where, required=False), where.at("phases"),
                       limits),
        client=client, allowlist=allowlist_section(doc, where, session),
        initial_session=session, initial_phase=phase, initial_q=q0, initial_epoch=epoch,
        watermarks=_watermarks(timing, where.at("timing")),
        degrade_after=integer(timing, "degrade_after", where.at("timing"), 3, minimum=1,
                              maximum=DEGRADE_AFTER_MAX),
        state_timeout_ns=_state_timeout(timing, where.at("timing"), period),
        cartesian=cartesian, kinematics=kinematics,
        motion=motion_config(mapping(doc, "motion", where, required=False), where.at("motion")),
        envelope=trial_bounds(doc, where, kinematics, envelope),
    )


def _state_timeout(timing: Mapping[str, Any], where: Where, period_ms: float) -> int | None:
    timeout = _optional_ms(timing, "state_timeout_ms", where)
    if timeout is not None and timeout < ms_to_ns(period_ms):
        raise where.at("state_timeout_ms").error(
            f"must be at least one control period ({period_ms:g} ms), got {timeout / 1e6:g}")
    return timeout


def motion_config(doc: Mapping[str, Any], where: Where) -> MotionConfig:
    default = MotionConfig()
    return MotionConfig(
        interpolator_jerk=number(doc, "interpolator_jerk", where, default.interpolator_jerk,
                                 positive=True, maximum=JERK_MAX),
        planner_velocity=number(doc, "planner_velocity", where, default.planner_velocity,
                                positive=True, maximum=VELOCITY_LIMIT_MAX),
        planner_acceleration=number(doc, "planner_acceleration", where,
                                    default.planner_acceleration, positive=True,
                                    maximum=ACCELERATION_LIMIT_MAX),
        planner_jerk=number(doc, "planner_jerk", where, default.planner_jerk, positive=True,
                            maximum=JERK_MAX),
        impedance=flag(doc, "impedance", where, default.impedance),
    )


# -- robot --------------------------------------------------------------------------------------


def robot_limits(robot: Mapping[str, Any], where: Where) -> JointLimits:
    dof = integer(robot, "dof", where, minimum=1, maximum=DOF_MAX)
    grip = robot.get("gripper_index")
    if grip is not None:
        grip = integer(robot, "gripper_index", where, minimum=0)
        if grip > dof:
            raise where.at("gripper_index").error(f"must be at most dof ({dof}), got {grip}")
    dim = dof + 1 if grip == dof else dof
    lower, upper = _position_limits(robot, where, dim, grip)
    velocity = _rate_limits(robot, "velocity_limits", where, dim, grip, VELOCITY_LIMIT_MAX)
    acceleration = _rate_limits(robot, "acceleration_limits", where, dim, grip,
                                ACCELERATION_LIMIT_MAX)
    try:
        return JointLimits(
            lower, upper, velocity, acceleration, gripper_index=grip,
            gripper_event_threshold=number(robot, "gripper_event_threshold", where, 1e-3,
                                           minimum=0, maximum=POSITION_LIMIT_MAX),
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
        bound = abs(number(robot, "position_limits", where, maximum=POSITION_LIMIT_MAX,
                           minimum=-POSITION_LIMIT_MAX))
        return np.full(dim, -bound), np.full(dim, bound)
    if isinstance(raw, dict):
        low_key = "lower" if "lower" in raw else "min"
        high_key = "upper" if "upper" in raw else "max"
        lower = vector(raw.get(low_key), here.at(low_key), bound=POSITION_LIMIT_MAX)
        upper = vector(raw.get(high_key), here.at(high_key), bound=POSITION_LIMIT_MAX)
    elif isinstance(raw, list) and all(isinstance(p, list) and len(p) == 2 for p in raw) and (
        len(raw) in (dim, dim - 1)
    ):
        pairs = [vector(p, here.at(i), 2, bound=POSITION_LIMIT_MAX) for i, p in enumerate(raw)]
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
    robot: Mapping[str, Any], key: str, where: Where, dim: int, grip: int | None,
    bound: float,
) -> np.ndarray:
    raw = robot.get(key)
    here = where.at(key)
    if raw is None:
        raise where.error(f"missing required key {key!r} (every joint needs one: a limit "
                          "never defaults to unbounded)")
    if is_number(raw):
        values = [number(robot, key, where, positive=True, maximum=bound)] * dim
    else:
        values = _pad_gripper(vector(raw, here, bound=bound), dim, grip, math.inf)
    if len(values) != dim:
        raise here.error(f"has {len(values)} entries, the robot has {dim} dimensions")
    if any(v <= 0 for v in values):
        raise here.error("must be positive")
    return np.array(values)


# -- phases -------------------------------------------------------------------------------------


def _phases(doc: Mapping[str, Any], where: Where, limits: JointLimits) -> PhaseBook:
    cards: dict[TaskPhase, PhaseCard] = {}
    span = joint_span(limits)
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
        cards[phase] = PhaseBook.make_card(phase, phase_policy(body, here, span), executor,
                                           proposals)
    return PhaseBook(cards)


def joint_span(limits: JointLimits) -> float:
    """The widest position range of an arm joint: no joint-space distance of this robot (a
    divergence, a projection) can be larger."""
    arm = limits.arm_mask
    return float(np.max(limits.upper[arm] - limits.lower[arm])) if arm.any() else 0.0


def phase_policy(body: Mapping[str, Any], where: Where, span: float) -> PhasePolicy:
    """One phase's admission bounds; ``span``: the widest joint range (see :func:`joint_span`)."""
    default = PhasePolicy()
    why = "the widest joint range of this robot: a larger distance is not a bound"
    return PhasePolicy(
        max_observation_age_ns=_ms(body, "max_observation_age_ms", where,
                                   default.max_observation_age_ns),
        max_action_age_ns=_ms(body, "max_action_age_ms", where, default.max_action_age_ns),
        max_divergence=_distance(body, "max_divergence", where, default.max_divergence, span,
                                 why),
        max_projection=_distance(body, "max_projection", where, default.max_projection, span,
                                 why),
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


def _distance(body: Mapping[str, Any], key: str, where: Where, default: float, span: float,
              why: str) -> float:
    value = number(body, key, where, default, minimum=0)
    in_range(value, where.at(key), maximum=span, why=why)
    return value


def _fraction(body: Mapping[str, Any], key: str, where: Where, default: float) -> float:
    value = number(body, key, where, default, positive=True)
    if value > 1:
        raise where.at(key).error(f"must be at most 1 (a fraction), got {value!r}")
    return value


def _ms(body: Mapping[str, Any], key: str, where: Where, default_ns: int) -> int:
    if body.get(key) is None:
        return default_ns
    return ms_to_ns(number(body, key, where, minimum=0, maximum=DURATION_MAX_MS))


def _optional_ms(body: Mapping[str, Any], key: str, where: Where) -> int | None:
    if body.get(key) is None:
        return None
    value = number(body, key, where, positive=True, maximum=DURATION_MAX_MS)
    if ms_to_ns(value) <= 0:
        raise where.at(key).error(f"must be at least 1 ns (0.000001 ms), got {value!r}")
    return ms_to_ns(value)


def _force_band(raw: Any, where: Where) -> ForceBand | None:
    if raw is None:
        return None
    if is_number(raw) and not (isinstance(raw, float) and math.isnan(raw)) and raw >= 0:
        in_range(float(raw), where, maximum=FORCE_MAX_N)
        return ForceBand(-float(raw), float(raw))
    if isinstance(raw, list) and len(raw) == 2:
        low, high = vector(raw, where, 2, bound=FORCE_MAX_N)
        if low <= high:
            return ForceBand(low, high)
    if isinstance(raw, dict):
        low = number(raw, "low", where, minimum=-FORCE_MAX_N, maximum=FORCE_MAX_N)
        high = number(raw, "high", where, minimum=-FORCE_MAX_N, maximum=FORCE_MAX_N)
        if low <= high:
            return ForceBand(low, high)
    raise where.error("must be a non-negative number, [low, high] or {low, high}")


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
