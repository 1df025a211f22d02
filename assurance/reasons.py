"""The bounded set of reason codes (docs/contract.md §3), plus the few this project added.

Values are stable on the wire and in journals: never rename or reuse one. The order of
definition is the canonical order in which a refusal lists its reasons.
"""

from __future__ import annotations

from collections.abc import Iterable
from enum import StrEnum


class ReasonCode(StrEnum):
    # content
    MALFORMED = "MALFORMED"
    NONFINITE = "NONFINITE"
    SCHEMA_MISMATCH = "SCHEMA_MISMATCH"
    # identity
    DUPLICATE = "DUPLICATE"
    ID_CONFLICT = "ID_CONFLICT"
    REORDERED = "REORDERED"
    OLD_QUEUE_EPOCH = "OLD_QUEUE_EPOCH"
    UNKNOWN_OBSERVATION = "UNKNOWN_OBSERVATION"
    # session and context
    HANDSHAKE_REQUIRED = "HANDSHAKE_REQUIRED"
    PROTOCOL_MISMATCH = "PROTOCOL_MISMATCH"
    CHECKPOINT_NOT_ALLOWED = "CHECKPOINT_NOT_ALLOWED"
    CONFIG_MISMATCH = "CONFIG_MISMATCH"
    SKILL_MISMATCH = "SKILL_MISMATCH"
    PHASE_MISMATCH = "PHASE_MISMATCH"
    CONTROLLER_MODE_MISMATCH = "CONTROLLER_MODE_MISMATCH"
    CALIBRATION_MISMATCH = "CALIBRATION_MISMATCH"
    # time
    CLOCK_INVALID = "CLOCK_INVALID"
    OBSERVATION_STALE = "OBSERVATION_STALE"
    EXPIRED = "EXPIRED"
    TRIM_FORBIDDEN = "TRIM_FORBIDDEN"
    # state and feasibility
    STATE_DIVERGED = "STATE_DIVERGED"
    INFEASIBLE = "INFEASIBLE"
    # authority
    NO_AUTHORITY = "NO_AUTHORITY"
    # fallback and FSM triggers
    LINK_LOST = "LINK_LOST"
    UNDERRUN = "UNDERRUN"
    OOD = "OOD"
    CONTACT_ANOMALY = "CONTACT_ANOMALY"
    CONTROLLER_REJECT = "CONTROLLER_REJECT"
    CONTROLLER_FAULT = "CONTROLLER_FAULT"
    WATCHDOG = "WATCHDOG"
    HUMAN_TAKEOVER = "HUMAN_TAKEOVER"
    E_STOP = "E_STOP"
    RECOVERY_ACCEPTED = "RECOVERY_ACCEPTED"
    GUARD_FAILED = "GUARD_FAILED"
    # --- added by warden (docs/contract.md §8, "Added names") ---
    OBSERVATION_ANSWERED = "OBSERVATION_ANSWERED"
    """The chunk cites an observation of this session that an admitted chunk already
    answered: it answers no pending request and is refused before any other work."""
    FUTURE_QUEUE_EPOCH = "FUTURE_QUEUE_EPOCH"
    """A chunk names a queue epoch this client has not issued yet."""
    GUARD_PASSED = "GUARD_PASSED"
    """A task transition whose guard held (the trigger of an accepted task transition)."""
    HANDSHAKE_ACCEPTED = "HANDSHAKE_ACCEPTED"
    """A new handshake was accepted: the task FSM enters VALIDATE."""
    HOLD_REQUESTED = "HOLD_REQUESTED"
    """The proposer (or the task FSM) asked for SAFE_HOLD."""
    OPERATOR_RELEASE = "OPERATOR_RELEASE"
    """The operator ended a takeover: authority goes to a validated hold, not to the policy."""
    OPERATOR_RESET = "OPERATOR_RESET"
    """The operator reset an E_STOP: the runtime leaves it toward a validated hold."""
    PHASE_OWNER = "PHASE_OWNER"
    """The phase contract gives motion to a classical owner (planner, contact law, evaluator)."""
    ENVELOPE = "ENVELOPE"
    """A bound of the trial envelope was reached: the tool left the workspace box (commanded
    or measured), or the wrist force exceeded its limit. The arm stops; the trial ends."""
    RECORDER_FAILED = "RECORDER_FAILED"
    """The run's journal or decision log can no longer be written (a full, failing or
    read-only disk): the arm stops and the run ends, since what followed could be neither
    replayed nor audited."""
    STATE_IMPLAUSIBLE = "STATE_IMPLAUSIBLE"
    """A state sample no joint of this arm can have produced (a velocity past its limit, a
    position step too large for the time since the last plausible sample, or off the path its
    reported velocities integrate to): it is never a measurement, never a hold target; the
    arm holds where it was last plausibly measured (SAFE_HOLD)."""
    COLLISION = "COLLISION"
    """An action of the chunk, or the motion into it, would bring two of the cell's solids
    closer than the phase's clearance (the arm's links, tool or held part against an
    obstacle or a keep-out zone, or two non-adjacent links against each other): the chunk is
    refused and the arm holds where its checked motion left it (SAFE_HOLD)."""
    RTC_PREFIX_MISMATCH = "RTC_PREFIX_MISMATCH"
    """A chunk conditioned on the committed prefix an observation carried (real-time
    chunking) whose first ``rtc_delay`` actions do not agree with that prefix within the
    phase's ``max_projection``, or that claims more of it than was sent, on another action
    grid, or for an observation that sent none: its seam would not be the committed motion."""
    RTC_DELAY_EXCEEDED = "RTC_DELAY_EXCEEDED"
    """A chunk conditioned on the committed prefix arrived after more of its actions were due
    than the ``rtc_delay`` it was conditioned on: the arm would run actions the policy planned
    without knowing what ran meanwhile."""
    CAMERA_LOST = "CAMERA_LOST"
    """A camera the policy sees through gave no fresh frame, or froze, and the manifest says
    losing it stops the phase (at once, or once its grace ran out without it coming back):
    no observation goes out without it, and the arm holds (SAFE_HOLD)."""


_ORDER = {code: index for index, code in enumerate(ReasonCode)}

# Contract codes only; the handshake's reason-code table is the full enum.
CONTRACT_CODES: frozenset[ReasonCode] = frozenset(
    code for code in ReasonCode if _ORDER[code] <= _ORDER[ReasonCode.GUARD_FAILED]
)


def canonical(codes: Iterable[ReasonCode]) -> tuple[ReasonCode, ...]:
    """Deduplicate and sort reason codes into the canonical order of the enum."""
    return tuple(sorted(set(codes), key=_ORDER.__getitem__))


def is_known(value: object) -> bool:
    """True when ``value`` names a reason code of this build."""
    return isinstance(value, str) and value in ReasonCode.__members__
