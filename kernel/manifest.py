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

from drivers.settings import SettingsError, settings_from_mapping
from kernel.core.config import CoreConfig
from kernel.safety.settings import SafetySettings, check_against_period
from kernel.scenario.config import build_config, check_keys
from kernel.scenario.fields import ScenarioError, Where


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
    ground_truth: bool = True
    """In simulation, VERIFY also asks the simulator how deep the part truly is, and passes only
    if that agrees with the measured evidence. False: the measured evidence alone decides, as
    on a real cell (which has no ground truth whatever this says)."""
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


@dataclass(frozen=True, slots=True)
class OperatorSettings:
    """``[operator]``: the socket a human commands the running arm through."""

    socket: str = ""
    """Its path; empty: ``$RUNTIME_DIRECTORY/operator.sock`` under systemd, else
    ``/run/warden/operator.sock``."""
    group: str = ""
    """Who may command: members of this group (and root); empty: warden's own group."""


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
    operator: OperatorSettings = field(default_factory=OperatorSettings)
    safety: SafetySettings | None = None
    """``[safety]``: the independent safety monitor and warden's heartbeat to it (None: no
    such table, warden sends no heartbeat and the monitor refuses the manifest)."""


_TOP_KEYS = frozenset({"name", "description", "cell", "driver", "emulator", "policy",
                       "journal", "task", "operator", "safety", *SCENARIO_SECTIONS})


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
    return Manifest(
        name=str(doc.get("name", path.stem)), path=path, core=core, sections=sections,
        driver_name=str(driver.pop("name")), driver_settings=driver,
        emulator=_settings(EmulatorSettings, doc, "emulator", where),
        cell=_settings(CellSettings, doc, "cell", where),
        policy=_settings(PolicySettings, doc, "policy", where),
        journal=_settings(JournalSettings, doc, "journal", where),
        task=dict(_table(doc, "task", where)),
        operator=_settings(OperatorSettings, doc, "operator", where),
        safety=_safety(doc, where, core.control_period_ns),
    )


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


def _safety(doc: Mapping[str, Any], where: Where, period_ns: int) -> SafetySettings | None:
    if "safety" not in doc:
        return None
    settings: SafetySettings = _settings(SafetySettings, doc, "safety", where)
    problem = check_against_period(settings, period_ns)
    if problem:
        raise ManifestError(f"{where.file}: safety.heartbeat_timeout_ms: {problem}")
    return settings


def _settings(cls: type, doc: Mapping[str, Any], key: str, where: Where) -> Any:
    try:
        return settings_from_mapping(cls, _table(doc, key, where), f"{where.file}: {key}")
    except SettingsError as error:
        raise ManifestError(str(error)) from None
