"""Shared set-up for runtime tests: a core built like a scenario, chunk makers, and the one
adapter through which these tests call the core.

Every call these tests make to the core goes through :func:`feed` and :func:`tick`, so a change
of the core's API (``Core.handle(event)`` / ``Core.tick(t)`` today) is a change here only.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from assurance.event_chunk import decode_event_chunk
from kernel.core.config import CoreConfig
from kernel.core.events import ChunkEvent, Event
from kernel.core.lines import Line
from kernel.core.runtime import Core
from kernel.core.tick import TickCommand
from kernel.scenario.config import build_config
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


def feed(core: Core, event: Event) -> list[Line]:
    """Apply one event; the decision-log lines it produced."""
    return core.handle(event)


def tick(core: Core, t_ns: int) -> tuple[TickCommand, list[Line]]:
    """Run the control tick at ``t_ns``: what goes out, and the lines it produced."""
    return core.tick(t_ns)
