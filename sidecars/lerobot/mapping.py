"""warden's observation → LeRobot's raw observation, and LeRobot's reply → warden's chunk.

What LeRobot can say and what it cannot (``docs/protocol.md``):

- Its reply says when each action is due, as ``TimedAction.timestamp = observation's timestamp
  + i/fps``, and which observation it answers, as ``timestep = observation's timestep + i``. The
  sidecar sends warden's own measured time of the joints (ns → s, warden's clock) and its own
  count, checks both come back exactly, and so writes ``first_action_time`` in warden's clock
  (``clock_domain = "client"``) without converting anything.
- It says nothing of checkpoint, skill, controller mode or calibration: the envelope repeats
  what the handshake agreed (and its fingerprint binds), and the checkpoint is the one the
  sidecar's configuration declares.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from peer.protocol import Observation
from sidecars.lerobot.config import SidecarConfig
from sidecars.lerobot.replies import TimedActionRecord

SPACING_TOLERANCE_S = 1e-6
"""How far a reply's action times may stray from ``i/fps`` (float rounding of a sum)."""


class ReplyMismatch(ValueError):
    """A well-formed reply that does not answer the observation sent, or not in its shape."""


@dataclass(frozen=True, slots=True)
class Sent:
    """One warden observation as it went to LeRobot."""

    observation: Observation
    q: np.ndarray
    timestep: int
    t_first: int
    """Warden's clock, ns: when the joints were measured (``t_state``, else ``t_event``)."""
    t_arrival: int
    """The sidecar's clock, ns."""

    @property
    def timestamp(self) -> float:
        return self.t_first / 1e9


def first_time(observation: Observation) -> int:
    return observation.t_event if observation.t_state is None else observation.t_state


def lerobot_observation(config: SidecarConfig, q: np.ndarray,
                        pixels: list[np.ndarray]) -> dict[str, Any]:
    """The robot's raw observation as LeRobot's client builds it: each joint by name, each
    camera by its LeRobot key (H×W×3 uint8), and the task."""
    raw: dict[str, Any] = {name: float(value) for name, value in
                           zip(config.joints, q, strict=True)}
    for camera, rgb in zip(config.cameras, pixels, strict=True):
        raw[camera.lerobot] = rgb
    if config.lerobot.task is not None:
        raw["task"] = config.lerobot.task
    return raw


def reply_actions(config: SidecarConfig, sent: Sent,
                  records: list[TimedActionRecord]) -> np.ndarray:
    """The H × D actions of a reply that answers ``sent``.

    Raises:
        ReplyMismatch: another observation's answer, actions not ``1/fps`` apart, more actions
            than asked for, or actions of another width.
    """
    if len(records) > config.lerobot.actions_per_chunk:
        raise ReplyMismatch(f"{len(records)} actions, asked for at most "
                            f"{config.lerobot.actions_per_chunk}")
    steps = [record.timestep for record in records]
    if steps != list(range(sent.timestep, sent.timestep + len(records))):
        raise ReplyMismatch(f"answers timesteps from {steps[0]}, the observation sent was "
                            f"{sent.timestep}")
    if records[0].timestamp != sent.timestamp:
        raise ReplyMismatch("its first action's time is not the observation's")
    dt = 1.0 / config.lerobot.fps
    for index, record in enumerate(records):
        if not math.isclose(record.timestamp - sent.timestamp, index * dt,
                            abs_tol=SPACING_TOLERANCE_S):
            raise ReplyMismatch(f"action {index} is not {dt:.6f} s after the one before: the "
                                "server's --fps is not lerobot.fps")
    widths = {record.action.shape[0] for record in records}
    if widths != {config.action_dim}:
        raise ReplyMismatch(f"actions of width {sorted(widths)}, the robot has "
                            f"{config.action_dim} joints")
    return np.stack([record.action for record in records])
