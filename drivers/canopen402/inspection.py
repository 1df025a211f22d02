"""What ``warden check`` compares on a CiA 402 bus: each drive's objects against the driver's
settings and the manifest's limits. Reads only (SDO uploads, and the statusword of the last
TPDO); run on the device thread after configure and activate.

- 0x6502 supported drive modes includes CSP, and 0x6061 shows CSP (configure selected it);
- the statusword: OPERATION ENABLED (the driver is active; the drive holds its target);
- 0x607D software position limits read back: the manifest's joint limits (the gripper: its
  stroke) in counts, as configure wrote them: a drive that clamped or refused them shows here;
- 0x607F max profile velocity: at least the manifest's velocity limit, in counts per second;
- 0x608F position encoder resolution times 0x6091 gear ratio: the ``counts_per_rev`` the
  manifest states (counts per turn of the joint; position units taken as encoder increments).
An object the drive (or its EDS) does not have is reported as not exercised.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from canopen.sdo import SdoAbortedError

from drivers.base import ControlConfig
from drivers.canopen402._sdk import Node402
from drivers.canopen402.drive_state import current_state
from drivers.canopen402.settings import CiA402Settings
from drivers.canopen402.tables import SUPPORTED_MODE_BITS, DriveState, Index, Mode
from drivers.canopen402.units import GRIPPER_STROKE_M
from drivers.readiness import Finding, judged, not_exercised

GRIPPER_READING_SLACK_M = 0.002
SCALE_TOLERANCE = 1e-9


@dataclass(frozen=True, slots=True)
class DriveConfig:
    """What one drive reports (None: the drive or its EDS has no such object)."""

    supported_modes: int
    mode_display: int
    state: DriveState
    limits: tuple[int, int]
    max_profile_velocity: int | None
    counts_per_turn: float | None
    """0x608F increments per motor turn times 0x6091 motor turns per shaft turn."""


def read_configuration(nodes: Sequence[Node402]) -> dict[int, DriveConfig]:
    """Every drive's objects (device thread only)."""
    return {node.id: _read(node) for node in nodes}


def _read(node: Node402) -> DriveConfig:
    sdo = node.sdo
    resolution = (_optional(lambda: sdo[Index.POSITION_ENCODER_RESOLUTION][1].raw),
                  _optional(lambda: sdo[Index.POSITION_ENCODER_RESOLUTION][2].raw),
                  _optional(lambda: sdo[Index.GEAR_RATIO][1].raw),
                  _optional(lambda: sdo[Index.GEAR_RATIO][2].raw))
    increments, motor_turns, gear_motor, gear_shaft = resolution
    known = None not in resolution and motor_turns and gear_shaft
    return DriveConfig(
        supported_modes=int(sdo[Index.SUPPORTED_MODES].raw),
        mode_display=int(sdo[Index.MODES_DISPLAY].raw),
        state=current_state(node),
        limits=(int(sdo[Index.SOFTWARE_LIMITS][1].raw), int(sdo[Index.SOFTWARE_LIMITS][2].raw)),
        max_profile_velocity=_optional(lambda: sdo[Index.MAX_PROFILE_VELOCITY].raw),
        counts_per_turn=(increments / motor_turns * gear_motor / gear_shaft) if known else None,
    )


def _optional(read: Callable[[], int]) -> int | None:
    """An object a drive need not have: None when the drive aborts with "object does not
    exist" (or any other abort) or the EDS does not describe it."""
    try:
        return int(read())
    except (SdoAbortedError, KeyError):
        return None


@dataclass(frozen=True, slots=True)
class Inspected:
    settings: CiA402Settings
    control: ControlConfig
    drives: Mapping[int, DriveConfig]
    gripper_m: float | None

    def grouped(self, value: Callable[[int], str], ids: Sequence[int] | None = None) -> str:
        """``nodes 1, 2: a; node 7 (gripper): b``: drives that report alike, together."""
        groups: dict[str, list[int]] = {}
        for node_id in ids if ids is not None else self.settings.drive_ids:
            groups.setdefault(value(node_id), []).append(node_id)
        return "; ".join(f"{self.label(ids)}: {text}" for text, ids in groups.items())

    def label(self, ids: Sequence[int]) -> str:
        names = ", ".join(f"{i} (gripper)" if i == self.settings.gripper_node else str(i)
                          for i in ids)
        return f"node{'s' if len(ids) > 1 else ''} {names}"


def findings(inspected: Inspected) -> tuple[Finding, ...]:
    return (_modes(inspected), _states(inspected), _limits(inspected),
            *_profile_velocity(inspected), *_scale(inspected), *_gripper(inspected),
            not_exercised("drives' watchdog on warden (0x1016)",
                          f"{inspected.settings.watchdog_ms} ms, armed by the first setpoint"
                          if inspected.settings.watchdog_ms else "off (watchdog_ms = 0)",
                          "armed only by a motion setpoint; check sends none"),
            not_exercised("joint zero (offset_counts)", "q = 0 where the manifest says",
                          "nothing a drive reports says where the joint's zero is; the measured "
                          "positions are checked against the manifest's limits"))


def _modes(s: Inspected) -> Finding:
    csp = Mode.CYCLIC_SYNCHRONOUS_POSITION
    problems = []
    lacking = [i for i in s.settings.drive_ids
               if not s.drives[i].supported_modes & SUPPORTED_MODE_BITS[csp]]
    if lacking:
        problems.append(f"{s.label(lacking)}: CSP not among the supported modes")
    other = [i for i in s.settings.drive_ids if s.drives[i].mode_display != csp]
    if other:
        problems.append(f"{s.label(other)}: not in CSP")
    return judged("modes (0x6502, 0x6061)", f"CSP supported, {int(csp)} (CSP) shown",
                  s.grouped(lambda i: f"0x{s.drives[i].supported_modes:08X}, "
                            f"{s.drives[i].mode_display}"), problems)


def _states(s: Inspected) -> Finding:
    off = [i for i in s.settings.drive_ids if s.drives[i].state is not (
        DriveState.OPERATION_ENABLED)]
    problems = [f"{s.label(off)}: not enabled (the driver is active)"] if off else []
    return judged("drive state (statusword)", str(DriveState.OPERATION_ENABLED),
                  s.grouped(lambda i: str(s.drives[i].state)), problems)


def _expected_limits(s: Inspected) -> dict[int, tuple[int, int]]:
    """0x607D as configure writes it: lower first whatever the axis's sign convention."""
    expected = {}
    for node_id, scale, low, high in zip(s.settings.node_ids, s.settings.joint_scales(),
                                         s.control.q_lower, s.control.q_upper, strict=True):
        a, b = scale.to_counts(low), scale.to_counts(high)
        expected[node_id] = (min(a, b), max(a, b))
    if s.settings.gripper_node is not None:
        gripper = s.settings.gripper_scale()
        expected[s.settings.gripper_node] = (gripper.to_counts(0.0),
                                             gripper.to_counts(GRIPPER_STROKE_M))
    return expected


def _limits(s: Inspected) -> Finding:
    expected = _expected_limits(s)
    wrong = [i for i in s.settings.drive_ids if s.drives[i].limits != expected[i]]
    problems = [f"{s.label([i])}: reads {list(s.drives[i].limits)}, configure wrote "
                f"{list(expected[i])}" for i in wrong]
    return judged("software position limits (0x607D)",
                  "the manifest's limits in counts: " + s.grouped(
                      lambda i: str(list(expected[i]))),
                  s.grouped(lambda i: str(list(s.drives[i].limits))), problems)


def _profile_velocity(s: Inspected) -> tuple[Finding, ...]:
    name, expected = "max profile velocity (0x607F)", "at least the manifest's velocity limit"
    joints = s.settings.node_ids
    if any(s.drives[i].max_profile_velocity is None for i in joints):
        return (not_exercised(name, expected, "a drive has no 0x607F (or its EDS does not "
                              "describe it)"),)
    problems = []
    for joint, (node_id, cpr) in enumerate(zip(joints, s.settings.counts_per_rev, strict=True)):
        wanted = s.control.v_max[joint] * cpr / (2 * math.pi)
        have = s.drives[node_id].max_profile_velocity or 0
        if have < wanted:
            problems.append(f"joint {joint} ({s.label([node_id])}): {have} counts/s is "
                            f"{have * 2 * math.pi / cpr:.3g} rad/s, below the manifest's "
                            f"{s.control.v_max[joint]:.3g} rad/s")
    return (judged(name, expected, s.grouped(
        lambda i: f"{s.drives[i].max_profile_velocity} counts/s", joints), problems),)


def _scale(s: Inspected) -> tuple[Finding, ...]:
    name = "position scale (0x608F x 0x6091)"
    expected = "counts_per_rev: " + ", ".join(f"{c:.10g}" for c in s.settings.counts_per_rev)
    joints = s.settings.node_ids
    if any(s.drives[i].counts_per_turn is None for i in joints):
        return (not_exercised(name, expected, "a drive has no 0x608F or 0x6091 (or its EDS "
                              "does not describe them)"),)
    problems = [f"joint {joint} ({s.label([node_id])}): the drive counts "
                f"{s.drives[node_id].counts_per_turn:.10g} per joint turn, the manifest "
                f"{cpr:.10g}: every position would be scaled wrong"
                for joint, (node_id, cpr) in enumerate(zip(joints, s.settings.counts_per_rev,
                                                           strict=True))
                if not math.isclose(s.drives[node_id].counts_per_turn or 0.0, cpr,
                                    rel_tol=SCALE_TOLERANCE)]
    return (judged(name, expected, s.grouped(
        lambda i: f"{s.drives[i].counts_per_turn:.10g} per turn", joints), problems),)


def _gripper(s: Inspected) -> tuple[Finding, ...]:
    if s.gripper_m is None:
        return ()
    opening = s.gripper_m
    inside = math.isfinite(opening) and (
        -GRIPPER_READING_SLACK_M <= opening <= GRIPPER_STROKE_M + GRIPPER_READING_SLACK_M)
    problems = [] if inside else ["past an end of the stroke: check gripper_counts_per_m"]
    return (judged("gripper opening", f"within [0, {GRIPPER_STROKE_M}] m", f"{opening:.4f} m",
                   problems),)
