"""The settings tables of a manifest that only a live run needs, as frozen msgspec Structs.

:mod:`kernel.manifest` reads them through :func:`kernel.tables.read_table` (every key known,
every value typed and within the range its field declares); they are here so each table's
meaning can be read on its own. ``[policy]`` is the link's own type
(:mod:`kernel.shell.link_settings`).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated

import msgspec
from msgspec import Meta

from assurance.kinematics import WorkspaceBox
from kernel.config.workspace import Coordinate, WristForce
from kernel.core.config import TrialBounds

# [emulator] is read by the safety monitor too, so its type lives below both readers.
from kernel.manifest_tables import EmulatorSettings as EmulatorSettings
from kernel.manifest_tables import PlantKind as PlantKind
from kernel.scenario import bounds


class ClockKind(StrEnum):
    WALL = "wall"
    """Real time: a kernel timer paces the control loop; the policy server is a process."""
    VIRTUAL = "virtual"
    """Lockstep: a virtual clock, the plant and an in-process policy step together (fast)."""


class CellSettings(msgspec.Struct, frozen=True, kw_only=True):
    cycles: Annotated[int, Meta(ge=1, le=bounds.CYCLES_MAX)] = 3
    clock: ClockKind = ClockKind.WALL
    seed: Annotated[int, Meta(ge=0, le=bounds.SEED_MAX)] = 7
    cycle_timeout_s: Annotated[float, Meta(ge=bounds.CYCLE_TIMEOUT_MIN_S,
                                           le=bounds.CYCLE_TIMEOUT_MAX_S)] = 30.0
    insertion_tolerance_m: Annotated[float, Meta(ge=0.0, le=bounds.LENGTH_MAX_M)] = 0.015
    """The evaluator's bar: peg depth below the fixture's top face that counts as inserted."""
    ground_truth: bool = True
    """In simulation, VERIFY also asks the simulator how deep the part truly is, and passes only
    if that agrees with the measured evidence. False: the measured evidence alone decides, as
    on a real cell (which has no ground truth whatever this says)."""
    simulated_operator: bool = True
    """Accept recovery automatically once the arm rests under a fallback owner. Simulation
    only: a manifest that drives a real device must set it false (a human recovers)."""


class OperatorSettings(msgspec.Struct, frozen=True, kw_only=True):
    """``[operator]``: the socket a human commands the running arm through."""

    socket: str = ""
    """Its path; empty: ``$RUNTIME_DIRECTORY/operator.sock`` under systemd, else
    ``/run/warden/operator.sock``."""
    group: str = ""
    """Who may command: members of this group (and root); empty: warden's own group."""


class FrameRecord(StrEnum):
    """What the run's record keeps of each camera frame an observation carried."""

    DIGESTS = "digests"
    """Its digest, capture time and calibration epoch, in the journal."""
    PIXELS = "pixels"
    """That, and the picture, as a PNG beside the journal (kernel/shell/frame_store.py)."""


class JournalSettings(msgspec.Struct, frozen=True, kw_only=True):
    enabled: bool = True
    directory: str = "runs"
    frames: FrameRecord = FrameRecord.DIGESTS


class MetricsSettings(msgspec.Struct, frozen=True, kw_only=True):
    """``[metrics]``: a Prometheus endpoint on this host (kernel/shell/metrics.py)."""

    port: Annotated[int, Meta(ge=1, le=65535)]
    host: str = "127.0.0.1"
    publish_interval_ms: Annotated[float, Meta(ge=50.0, le=5_000.0)] = 500.0


class WorkspaceSection(msgspec.Struct, frozen=True, kw_only=True):
    lower: tuple[float, float, float]
    upper: tuple[float, float, float]


class EnvelopeSection(msgspec.Struct, frozen=True, kw_only=True):
    """A scenario's ``envelope`` section, as a trial's journal header records it."""

    workspace: WorkspaceSection
    max_wrist_force_n: float


class TrialEnvelope(msgspec.Struct, frozen=True, kw_only=True):
    """``[trial]``: every bound of a bounded trial, all of them required."""

    max_cycles: Annotated[int, Meta(ge=1, le=1000)]
    max_duration_s: Annotated[float, Meta(ge=1.0, le=86_400.0)]
    workspace_lower: tuple[Coordinate, Coordinate, Coordinate]
    """The box the tool (TCP) must stay in, base frame, metres: its lower corner..."""
    workspace_upper: tuple[Coordinate, Coordinate, Coordinate]
    """...and its upper corner (:func:`kernel.config.workspace.workspace_box` checks it)."""
    speed_scale: Annotated[float, Meta(ge=0.01, le=1.0)]
    """Every joint's velocity limit is multiplied by this (0 < scale <= 1)."""
    max_wrist_force_n: WristForce

    def bounds(self) -> TrialBounds:
        """What the core enforces (the box was checked when the manifest was read)."""
        return TrialBounds(WorkspaceBox(list(self.workspace_lower), list(self.workspace_upper)),
                           self.max_wrist_force_n)

    def section(self) -> EnvelopeSection:
        """The scenario's ``envelope`` section the journal's header records (a replay reads
        it back with :func:`kernel.config.envelope.trial_bounds`)."""
        return EnvelopeSection(
            workspace=WorkspaceSection(lower=self.workspace_lower, upper=self.workspace_upper),
            max_wrist_force_n=self.max_wrist_force_n)
