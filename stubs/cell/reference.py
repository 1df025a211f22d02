"""The reference policy as a stand-in for a cell: as a server process, or in process.

Both propose the pre-contact approach of the assembly task: from wherever the arm is observed,
toward the pre-insert pose (solved once from the task's layout), at a bounded joint speed, with
the manifest's latency model and noise. They offer exactly what the manifest's session accepts.
The kernel finds them through the ``warden.policies`` entry points (``reference``, ``local``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from assurance.handshake import HandshakeOffer
from kernel.app.context import CellContext
from kernel.manifest import Manifest
from kernel.shell.timer import Clock
from stubs.cell.local_policy import LocalPolicyConfig, LocalPolicyLink, local_timing
from stubs.policy_server.policy import InsertionPolicy, LatencyModel
from stubs.process import EmulatorProcess

POLICY_SPEED = 0.3
"""rad/s: how fast the scripted policy moves each joint toward its goal."""
POLICY_ACCELERATION = 3.0
"""rad/s²: how briskly the scripted policy speeds up and brakes."""


def offer_for(manifest: Manifest) -> HandshakeOffer:
    """The reference server's offer: exactly what this manifest's session accepts."""
    session = manifest.sections.table("session")
    return HandshakeOffer(
        policy_checkpoint=session["policy_checkpoint"], config_hash=session["config_hash"],
        observation_keys=tuple(session.get("observation_keys", ())),
        action_dim=int(session.get("action_dim", 6)),
        action_units=session.get("action_units", "rad"),
        action_frame=session.get("action_frame", "joint"),
        chunk_horizon=manifest.policy.chunk_horizon,
        protocol=tuple(session.get("protocol", (1, 1))), skill=session.get("skill"),
        skill_version=session["skill_version"], controller_mode=session["controller_mode"],
        calibration_epoch=str(session["calibration_epoch"]),
    )


def policy_goal(context: CellContext) -> np.ndarray:
    """Where the scripted policy heads: the pre-insert pose, solved through the staging pose
    (so the solution is on the branch the arm arrives on)."""
    layout, planner = context.layout, context.planner
    staging = planner.solve(layout.home_q, layout.staging_tcp)
    return planner.solve(staging, layout.pre_insert_tcp)


def policy_model(manifest: Manifest, goal: np.ndarray) -> tuple[InsertionPolicy, LatencyModel]:
    settings = manifest.policy
    policy = InsertionPolicy(goal=goal, max_speed=POLICY_SPEED, noise_std=settings.noise_rad,
                             horizon=settings.chunk_horizon,
                             action_dt_s=settings.action_dt_ms / 1000.0,
                             max_acceleration=POLICY_ACCELERATION)
    return policy, LatencyModel(settings.latency_median_ms, settings.latency_p95_ms)


def local_policy(context: CellContext, clock: Clock) -> LocalPolicyLink:
    """The ``local`` policy: in process, answering the core's requests on the virtual clock."""
    manifest = context.manifest
    policy, latency = policy_model(manifest, policy_goal(context))
    return LocalPolicyLink(
        LocalPolicyConfig(offer_for(manifest), policy, latency, seed=manifest.cell.seed,
                          timing=local_timing(manifest.policy)),
        context.gateway)


class ReferenceServer:
    """The ``reference`` policy: ``warden serve-policy`` as a child process on loopback."""

    def __init__(self, context: CellContext) -> None:
        self.manifest = context.manifest
        self.goal = policy_goal(context)
        self.process: EmulatorProcess | None = None

    def start(self) -> str:
        """Start the server; returns its websocket URL."""
        self.process = EmulatorProcess("stubs.policy_server", *self._args()).start()
        return f"ws://{self.manifest.policy.host}:{self.process.info['port']}"

    def stop(self) -> None:
        if self.process is not None:
            self.process.stop()
            self.process = None

    def _args(self) -> list[str]:
        settings = self.manifest.policy
        return server_args(self.manifest, self.goal, settings.host, settings.port)


def server_args(manifest: Manifest, goal: np.ndarray, host: str, port: int) -> list[str]:
    """The server's command line for this manifest's cell, listening on ``host:port``."""
    settings = manifest.policy
    offer = offer_for(manifest)
    return [
        "--host", host, "--port", str(port),
        "--goal", ",".join(f"{v:.9f}" for v in goal),
        "--max-speed", str(POLICY_SPEED), "--max-acceleration", str(POLICY_ACCELERATION),
        "--noise", str(settings.noise_rad), "--horizon", str(settings.chunk_horizon),
        "--action-dt-ms", str(settings.action_dt_ms),
        "--latency-median-ms", str(settings.latency_median_ms),
        "--latency-p95-ms", str(settings.latency_p95_ms),
        "--clock-offset-ms", str(settings.clock_offset_ms),
        "--seed", str(manifest.cell.seed),
        "--checkpoint", offer.policy_checkpoint, "--config-hash", offer.config_hash,
        "--observation-keys", ",".join(offer.observation_keys),
        "--action-dim", str(offer.action_dim), "--action-units", offer.action_units,
        "--action-frame", offer.action_frame, "--skill", offer.skill or "",
        "--skill-version", offer.skill_version or "",
        "--controller-mode", offer.controller_mode or "",
        "--calibration-epoch", str(offer.calibration_epoch),
        "--protocol", f"{offer.protocol[0]},{offer.protocol[1]}",
        "--replacement-policy", "blend",
        *(["--rtc"] if settings.rtc else []),
        *(arg for camera in manifest.cameras
          for arg in ("--camera", f"{camera.name}:{camera.width}x{camera.height}")),
    ]


def reference_server(context: CellContext, _: Any = None) -> ReferenceServer:
    return ReferenceServer(context)


def serve(context: CellContext, host: str, port: int) -> int:
    """``warden serve-policy``: the server :class:`ReferenceServer` would launch for this cell,
    in this process, on ``host:port``, until SIGINT or SIGTERM."""
    from stubs.policy_server.__main__ import main

    return main(server_args(context.manifest, policy_goal(context), host, port))
