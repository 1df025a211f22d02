"""A trial's envelope against the limits it must lie inside: the arm's reach (from the robot
model and its joints), the manifest's velocity limits and the safety monitor's force limit.

An envelope that bounds nothing is not an envelope: a box wider than anything the arm can
reach, a wrist force limit above the one the monitor already stops at (the monitor would act
first, so the envelope's limit is never what ends the trial), are refused. A ``speed_scale`` of
1 is the manifest's own velocity limits, not wider than them but not reduced either: it runs
only with an explicit ``--full-speed``, which the log, the card and the summary all say.
"""

from __future__ import annotations

import numpy as np
import structlog

from assurance.kinematics import ArmKinematics
from kernel.manifest import Manifest, ManifestError, TrialEnvelope

log = structlog.get_logger("warden.trial")


def check_envelope(manifest: Manifest, envelope: TrialEnvelope, full_speed: bool) -> None:
    """Refuse an envelope wider than the arm's reach or the monitor's force limit, and one
    that does not reduce the speed unless ``full_speed``.

    Raises:
        ManifestError: naming the ``[trial]`` key, its value and the limit it exceeds.
    """
    where = f"{manifest.path}: trial"
    kinematics = manifest.core.kinematics
    if kinematics is not None:  # without a model, the envelope section was refused already
        _inside_reach(where, envelope, reach_m(kinematics))
    safety = manifest.safety
    monitor_n = safety.max_wrist_force_n if safety is not None else None
    if monitor_n is not None and envelope.max_wrist_force_n > monitor_n:
        raise ManifestError(
            f"{where}.max_wrist_force_n: {envelope.max_wrist_force_n:g} N is above the safety "
            f"monitor's own limit (safety.max_wrist_force_n = {monitor_n:g} N): the monitor "
            "would stop the arm before this bound is ever reached; give at most that")
    if envelope.speed_scale >= 1.0:
        if not full_speed:
            raise ManifestError(
                f"{where}.speed_scale: {envelope.speed_scale:g} reduces nothing (the joints run "
                "at the manifest's own velocity limits); give a scale below 1, or pass "
                "--full-speed to run at those limits (logged)")
        log.warning("trial at full speed", run=manifest.name, speed_scale=envelope.speed_scale,
                    opt_in="--full-speed")


def reach_m(kinematics: ArmKinematics) -> float:
    """An upper bound of the tool centre point's distance from the base frame's origin: the
    length of every link of the chain and the tool's offset, end to end (no pose is farther,
    by the triangle inequality)."""
    model = kinematics.model
    links = sum(float(np.linalg.norm(model.jointPlacements[j].translation))
                for j in range(1, model.njoints))
    tcp = model.frames[model.getFrameId(kinematics.config.tcp_frame)]
    return links + float(np.linalg.norm(tcp.placement.translation))


def _inside_reach(where: str, envelope: TrialEnvelope, reach: float) -> None:
    corners = (("workspace_lower", envelope.workspace_lower),
               ("workspace_upper", envelope.workspace_upper))
    for key, corner in corners:
        for axis, value in enumerate(corner):
            if abs(value) > reach:
                raise ManifestError(
                    f"{where}.{key}[{axis}]: {value:g} m is beyond the arm's reach ({reach:.3g} m "
                    "from the base, its links end to end in the robot model): a box wider than "
                    "the arm can reach bounds nothing there; give corners within "
                    f"±{reach:.3g} m")
