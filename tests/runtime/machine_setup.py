"""Shared set-up for runtime tests: a core built like a scenario, chunk makers, and the one
adapter through which these tests call the core.

Every call these tests make to the core goes through :func:`feed` and :func:`tick`, so a change
of the core's API (``Core.step(event) -> Step`` today) is a change here only. A job the core asks
for (the exact projection, a Cartesian mapping) runs at once, at the instant it was asked for,
as in a scenario replay.
"""

from __future__ import annotations

from typing import Any

import msgspec
import numpy as np

from assurance.event_chunk import decode_event_chunk
from kernel.config.build import build_config
from kernel.core.config import CoreConfig
from kernel.core.effects import Compute, Motion
from kernel.core.events import ChunkEvent, ComputedEvent, Event, TickEvent
from kernel.core.jobs import run_job
from kernel.core.lines import Line, SentRef, TickLine
from kernel.core.runtime import Core
from kernel.scenario.fields import Where
from tools.scenarios.base import IDENTITY, ScenarioSpec

DT_MS = 10
PERIOD_MS = 2


def core_config(phase: str = "FREE_SPACE", robot: dict[str, Any] | None = None,
                **timing: Any) -> CoreConfig:
    """The standard cell (or ``robot``, a scenario file's robot section) as a core config."""
    spec = ScenarioSpec(name="machine", description="", events=[], until=0, expect=[],
                        phase=phase, timing=timing, robot=robot)
    return build_config(spec.document(), Where("machine", ""))


def chunk_fields(
    chunk_id: str, sequence: int, epoch: int, phase: str, observation: str, obs_t: float,
    first: float, actions: np.ndarray, **overrides: Any,
) -> dict[str, Any]:
    fields = {
        "chunk_id": chunk_id, "sequence": sequence, "queue_epoch": epoch, **IDENTITY,
        "task_phase": phase, "observation_id": observation, "observation_event_time": obs_t,
        "clock_domain": "client", "inference_start": obs_t + 2, "first_action_time": first,
        "action_dt": DT_MS, "actions": np.round(actions, 9).tolist(),
        "replacement_policy": "replace",
    }
    fields.update(overrides)
    return fields


def chunk_event(t_ms: float, fields: dict[str, Any]) -> ChunkEvent:
    t = round(t_ms * 1_000_000)
    return ChunkEvent(t, decode_event_chunk(fields, t))


# --- the adapter ---------------------------------------------------------------------------------


class Ticked(msgspec.Struct, frozen=True, eq=False):
    """What a tick sent: the queued action in force (``sent``, its joint ``target`` and the
    time of the observation it was conditioned on) when the policy owns the tick, and the
    motion effect that reached the arm."""

    sent: SentRef | None
    target: np.ndarray | None
    t_obs: int | None
    motion: Motion | None
    reason: str | None


def feed(core: Core, event: Event) -> list[Line]:
    """Apply one event (and any job it asks for); the decision-log lines it produced."""
    step = core.step(event)
    lines = list(step.lines)
    for effect in step.effects:
        if isinstance(effect, Compute):
            config = core.config
            result = run_job(effect.job, config.limits, config.cartesian)
            lines += feed(core, ComputedEvent(t=event.t, result=result))
    return lines


def tick(core: Core, t_ns: int) -> tuple[Ticked, list[Line]]:
    """Run the control tick at ``t_ns``: what went out, and the lines it produced."""
    step = core.step(TickEvent(t=t_ns))
    line = next(line for line in step.lines if isinstance(line, TickLine))
    row = core.inspect_state().last_setpoint
    if line.sent is None or row is None:
        return Ticked(None, None, None, step.motion, line.reason), list(step.lines)
    return Ticked(line.sent, np.asarray(row.q), row.t_obs, step.motion,
                  line.reason), list(step.lines)
