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
from kernel.config.cameras import cameras_section
from kernel.config.envelope import trial_bounds
from kernel.config.geometry import cell_collision
from kernel.config.kinematics import cartesian_mapper, robot_kinematics
from kernel.config.session import allowlist_section, session_section, state_vector
from kernel.core.config import CoreConfig, MotionConfig, TrialBounds
from kernel.manifest_tables import ROBOT_KEYS, control_period_ms, robot_limits_table
from kernel.scenario.bounds import (
    ACCELERATION_LIMIT_MAX,
    DEGRADE_AFTER_MAX,
    DURATION_MAX_MS,
    FORCE_MAX_N,
    JERK_MAX,
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
from skills.phases import Executor, PhaseBook, PhaseCard, TaskPhase

SECTION_KEYS: dict[str, frozenset[str]] = {
    "robot": ROBOT_KEYS,
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
    period = control_period_ms(timing, where.at("timing"))
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
        collision=cell_collision(doc, where, kinematics),
        cameras=cameras_section(doc, where, client.observation_keys),
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
    """The core's joint limits, from the one ``[robot]`` parser the safety monitor shares."""
    table = robot_limits_table(robot, where)
    try:
        return JointLimits(
            np.array(table.lower), np.array(table.upper), np.array(table.velocity),
            np.array(table.acceleration), gripper_index=table.gripper_index,
            gripper_event_threshold=table.gripper_event_threshold,
        )
    except ValueError as error:
        raise where.error(str(error)) from None


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
