"""Deployment manifests (TOML): what a run drives, with which limits, policy and journal.

A manifest carries the same robot, timing, phases, session and allowlist sections as a scenario
file (validated by the same code) plus what only a live run needs: the cell, the driver (and
its emulator in simulation), the policy server, the journal. Unlike a scenario, a manifest
refuses unknown keys: a typo in a deployment file must never be silently ignored. Every error
names the file and the key, and the CLI exits 2.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

from assurance.clock import ms_to_ns, ns_to_ms
from drivers.settings import SettingsError, settings_from_mapping
from kernel.core.config import CoreConfig
from kernel.scenario.config import build_config, check_keys
from kernel.scenario.fields import ScenarioError, Where
from kernel.wire import MAX_FRAME_BYTES
from skills.phases import Executor, TaskPhase


class ManifestError(ScenarioError):
    """A manifest that cannot be used; the message names the file and the key."""


class ClockKind(StrEnum):
    WALL = "wall"
    """Real time: a kernel timer paces the control loop; the policy server is a process."""
    VIRTUAL = "virtual"
    """Lockstep: a virtual clock, the plant and an in-process policy step together (fast)."""


SCENARIO_SECTIONS = ("robot", "timing", "phases", "session", "allowlist", "motion")
"""The sections a manifest shares with a scenario (and a journal's header repeats)."""


@dataclass(frozen=True, slots=True)
class CellSettings:
    cycles: int = 3
    clock: ClockKind = ClockKind.WALL
    seed: int = 7
    cycle_timeout_s: float = 30.0
    insertion_tolerance_m: float = 0.015
    """The evaluator's bar: peg depth below the fixture's top face that counts as inserted."""
    simulated_operator: bool = True
    """Accept recovery automatically once the arm rests under a fallback owner. Simulation
    only: a manifest that drives a real device must set it false (a human recovers)."""


class PlantKind(StrEnum):
    MUJOCO = "mujoco"
    KINEMATIC = "kinematic"


@dataclass(frozen=True, slots=True)
class EmulatorSettings:
    """``[emulator]``: simulation only."""

    launch: bool = True
    plant: PlantKind = PlantKind.MUJOCO
    host: str = ""


@dataclass(frozen=True, slots=True)
class PolicySettings:
    launch: bool = True
    host: str = "127.0.0.1"
    port: int = 0
    latency_median_ms: float = 30.0
    latency_p95_ms: float = 60.0
    chunk_horizon: int = 20
    action_dt_ms: float = 20.0
    noise_rad: float = 0.0005
    clock_offset_ms: float = 0.0
    # What one policy peer may cost (docs/manifest.md, [policy]; kernel/shell/link_budget.py)
    max_frame_bytes: int = 65536
    max_frames_per_s: float = 1000.0
    max_chunks_per_s: float = 100.0
    max_requests_in_flight: int = 4
    request_timeout_ms: float = 250.0
    admissions_per_period: int = 1
    heartbeat_interval_ms: float = 100.0
    heartbeat_timeout_ms: float = 350.0

    def __post_init__(self) -> None:
        for name in ("max_frames_per_s", "max_chunks_per_s", "request_timeout_ms",
                     "heartbeat_interval_ms"):
            if not getattr(self, name) > 0:  # also refuses NaN
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        for name in ("max_requests_in_flight", "admissions_per_period"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)!r}")
        if not 1 <= self.max_frame_bytes <= MAX_FRAME_BYTES:
            raise ValueError(f"max_frame_bytes must be in 1..{MAX_FRAME_BYTES}, got "
                             f"{self.max_frame_bytes!r}")
        if not self.heartbeat_timeout_ms > self.heartbeat_interval_ms:
            raise ValueError(f"heartbeat_timeout_ms ({self.heartbeat_timeout_ms!r}) must be "
                             f"longer than heartbeat_interval_ms ({self.heartbeat_interval_ms})")

    @property
    def link_loss_bound_ms(self) -> float:
        """How long a dead link may go unnoticed, with one heartbeat of margin."""
        return self.heartbeat_timeout_ms + self.heartbeat_interval_ms


@dataclass(frozen=True, slots=True)
class JournalSettings:
    enabled: bool = True
    directory: str = "runs"


@dataclass(frozen=True, slots=True, eq=False)
class Manifest:
    name: str
    path: Path
    core: CoreConfig
    sections: dict[str, Any]
    """The scenario sections as written (the journal's header repeats them)."""
    driver_name: str
    driver_settings: dict[str, Any]
    emulator: EmulatorSettings
    cell: CellSettings = field(default_factory=CellSettings)
    policy: PolicySettings = field(default_factory=PolicySettings)
    journal: JournalSettings = field(default_factory=JournalSettings)
    task: dict[str, Any] = field(default_factory=dict)
    """``[task]`` as written: the assembly task's layout (:mod:`kernel.app.task` checks it)."""


_TOP_KEYS = frozenset({"name", "description", "cell", "driver", "emulator", "policy",
                       "journal", "task", *SCENARIO_SECTIONS})


def load_manifest(path: str | Path) -> Manifest:
    path = Path(path)
    where = Where(str(path), "")
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as error:
        raise ManifestError(f"{path}: cannot read file: {error.strerror or error}") from None
    except tomllib.TOMLDecodeError as error:
        raise ManifestError(f"{path}: not valid TOML: {error}") from None
    _refuse_unknown(doc, where)
    sections = {key: doc[key] for key in SCENARIO_SECTIONS if key in doc}
    try:
        core = build_config(sections, where)
    except ScenarioError as error:
        raise ManifestError(str(error)) from None
    driver = dict(_table(doc, "driver", where))
    if "name" not in driver:
        raise where.at("driver").error("missing required key 'name'")
    if driver["name"] != "sim" and core.state_timeout_ns is None:
        raise where.at("timing").error(
            "missing required key 'state_timeout_ms': a real device needs the state watchdog "
            "(the arm stops when its state samples stop)")
    policy = _settings(PolicySettings, doc, "policy", where)
    _check_link_loss_first(core, policy, where)
    return Manifest(
        name=str(doc.get("name", path.stem)), path=path, core=core, sections=sections,
        driver_name=str(driver.pop("name")), driver_settings=driver,
        emulator=_settings(EmulatorSettings, doc, "emulator", where),
        cell=_settings(CellSettings, doc, "cell", where),
        policy=policy, journal=_settings(JournalSettings, doc, "journal", where),
        task=dict(_table(doc, "task", where)),
    )


def _check_link_loss_first(core: CoreConfig, policy: PolicySettings, where: Where) -> None:
    """A dead link must be DEGRADED (a new handshake recovers) before the queue it starves
    escalates to SAFE_HOLD (only an operator recovers): every phase the policy executes must
    hold on an empty queue longer than the link takes to be declared lost."""
    bound_ns = ms_to_ns(policy.link_loss_bound_ms)
    for phase in TaskPhase:
        card = core.phases.card(phase)
        if card.executor is not Executor.POLICY or not card.takes_proposals:
            continue
        if card.policy.underrun_limit_ns <= bound_ns:
            implied = " (max_action_age_ms)" if card.policy.max_underrun_ns is None else ""
            raise where.at("phases").at(phase).at("max_underrun_ms").error(
                f"{ns_to_ms(card.policy.underrun_limit_ns)} ms{implied} must be longer than "
                "policy.heartbeat_timeout_ms + heartbeat_interval_ms = "
                f"{policy.link_loss_bound_ms:g} ms: a dead policy link must end in DEGRADED, "
                "not in an underrun SAFE_HOLD that only an operator can end")


def _refuse_unknown(doc: Mapping[str, Any], where: Where) -> None:
    for key in doc:
        if key not in _TOP_KEYS:
            raise where.at(key).error(f"unknown key (known: {', '.join(sorted(_TOP_KEYS))})")
    for section in SCENARIO_SECTIONS:
        if section != "allowlist":
            _table(doc, section, where)
    check_keys(doc, where)
    for phase, body in _table(doc, "phases", where).items():
        if not isinstance(body, dict):
            raise where.at("phases").at(phase).error("must be a table")
    allowlist = doc.get("allowlist", [])
    if not isinstance(allowlist, list):
        raise where.at("allowlist").error("must be an array of tables ([[allowlist]])")
    for index, entry in enumerate(allowlist):
        if isinstance(entry, dict):
            _check_keys(entry, frozenset({"policy_checkpoint", "config_hash"}),
                        where.at("allowlist").at(index))


def _check_keys(table: Mapping[str, Any], known: frozenset[str], where: Where) -> None:
    for key in table:
        if key not in known:
            raise where.at(key).error(f"unknown key (known: {', '.join(sorted(known))})")


def _table(doc: Mapping[str, Any], key: str, where: Where) -> Mapping[str, Any]:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        raise where.at(key).error("must be a table")
    return value


def _settings(cls: type, doc: Mapping[str, Any], key: str, where: Where) -> Any:
    try:
        return settings_from_mapping(cls, _table(doc, key, where), f"{where.file}: {key}")
    except SettingsError as error:
        raise ManifestError(str(error)) from None
