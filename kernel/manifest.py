"""Deployment manifests (TOML): what a run drives, with which limits, policy and journal.

A manifest carries the same robot, timing, phases, session and allowlist sections as a scenario
file (validated by the same code) plus what only a live run needs: the cell, the driver (and
its emulator in simulation), the policy server, the journal. Unlike a scenario, a manifest
refuses unknown keys: a typo in a deployment file must never be silently ignored. Every error
names the file and the key, and the CLI exits 2.
"""

from __future__ import annotations

import dataclasses
import hashlib
import ipaddress
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from assurance.clock import ms_to_ns, ns_to_ms
from kernel.app.task_settings import TaskSettings, check_home
from kernel.config.build import build_config, check_keys
from kernel.config.workspace import workspace_box
from kernel.core.config import CoreConfig
from kernel.manifest_cameras import CameraSettings, cameras_table, check_cameras_travel
from kernel.manifest_tables import (
    decode_driver_settings,
    driver_table,
    parse_toml,
    run_name,
    safety_table,
    table,
)
from kernel.safety.settings import SafetySettings
from kernel.scenario.document import check_document, decoded, read_bytes
from kernel.scenario.fields import ScenarioError, Where
from kernel.sections import ScenarioSections
from kernel.settings import (
    CellSettings,
    ClockKind,
    EmulatorSettings,
    JournalSettings,
    MetricsSettings,
    OperatorSettings,
    PlantKind,
    TrialEnvelope,
)
from kernel.shell.link_security import (
    LinkSecurity,
    SecurityError,
    check_shape,
    link_security,
)
from kernel.shell.link_settings import PolicyProtocol, PolicySettings
from kernel.tables import read_table
from skills.phases import Executor, TaskPhase

__all__ = ["CellSettings", "ClockKind", "EmulatorSettings", "JournalSettings", "Manifest",
           "ManifestError", "OperatorSettings", "PlantKind", "PolicySettings", "TrialEnvelope",
           "load_manifest"]


class ManifestError(ScenarioError):
    """A manifest that cannot be used; the message names the file and the key."""


SCENARIO_SECTIONS = ("robot", "timing", "phases", "session", "allowlist", "motion", "geometry")
"""The sections a manifest shares with a scenario (and a journal's header repeats)."""


@dataclass(frozen=True, slots=True, eq=False)
class Manifest:
    name: str
    path: Path
    core: CoreConfig
    sections: ScenarioSections
    """The scenario sections as written, encoded and immutable (the journal's header repeats
    them; :mod:`kernel.sections` says why they stay the document and not a typed tree)."""
    driver_name: str
    driver_settings: Any
    """``[driver]`` without ``name``, decoded once into the settings type that driver declares
    (``settings_type`` of :class:`drivers.base.Driver`, resolved by :mod:`drivers.registry`)."""
    emulator: EmulatorSettings
    cell: CellSettings = field(default_factory=CellSettings)
    policy: PolicySettings = field(default_factory=PolicySettings)
    link_security: LinkSecurity = field(default_factory=LinkSecurity)
    """``[policy.tls]`` and ``[policy.auth]`` as loaded: the TLS context and the token, every
    file read while the manifest loaded (kernel/shell/link_security.py)."""
    journal: JournalSettings = field(default_factory=JournalSettings)
    task: TaskSettings | None = None
    """``[task]``: the assembly task's layout, checked on load (None: no such table; the
    assembly task then refuses the manifest, naming the first key it needs)."""
    operator: OperatorSettings = field(default_factory=OperatorSettings)
    trial: TrialEnvelope | None = None
    """``[trial]``: the envelope a bounded trial runs in (``warden trial`` requires it)."""
    digest: str = ""
    """SHA-256 of the exact bytes that were parsed (the journal records it)."""
    signer: str | None = None
    """The key id that verified those bytes, when a signature was checked before parsing."""
    safety: SafetySettings | None = None
    """``[safety]``: the independent safety monitor and warden's heartbeat to it (None: no
    such table, warden sends no heartbeat and the monitor refuses the manifest)."""
    cameras: tuple[CameraSettings, ...] = ()
    """``[[cameras]]`` (kernel/manifest_cameras.py)."""
    metrics: MetricsSettings | None = None
    """``[metrics]``: a Prometheus endpoint (None: no such table, none is served)."""


_TOP_KEYS = frozenset({"name", "description", "cell", "driver", "emulator", "policy",
                       "journal", "task", "operator", "trial", "safety", "cameras",
                       "metrics", *SCENARIO_SECTIONS})


def load_manifest(path: str | Path, content: bytes | None = None,
                  signer: str | None = None, credentials: bool = True) -> Manifest:
    """Read and check a manifest: every key known, every value typed and within its bounds.

    ``content``: the bytes to parse instead of reading ``path`` (the bytes a signature was
    verified on, so that what is checked is what runs); ``signer``: the key id that verified
    them; ``credentials``: read the policy link's CA bundle, client key and token now (False
    for a command that never connects to the policy server and may run as another user or on
    another machine: ``warden operator``, ``warden manifest sign``; its ``link_security`` is
    then the plain default, never to be connected with).

    Raises:
        ManifestError: naming the file and the key, for anything a run could not use; nothing
            has started when it is raised.
    """
    path = Path(path)
    try:
        data = read_bytes(path, str(path)) if content is None else content
        manifest = _load(path, decoded(data, str(path)), credentials)
    except ManifestError:
        raise
    except ScenarioError as error:  # the sections a manifest shares with a scenario
        raise ManifestError(str(error)) from None
    return dataclasses.replace(manifest, digest=hashlib.sha256(data).hexdigest(),
                               signer=signer)


def _load(path: Path, raw: str, credentials: bool) -> Manifest:
    where = Where(str(path), "")
    doc = parse_toml(raw, str(path))
    check_document(doc, where)
    _refuse_unknown(doc, where)
    written = {key: doc[key] for key in SCENARIO_SECTIONS if key in doc}
    driver_name, driver = driver_table(doc, where)
    cameras = cameras_table(doc, where, driver_name)
    if cameras:  # the core's part of [[cameras]], which the journal's header repeats
        written["cameras"] = [camera.loss_entry() for camera in cameras]
    core = build_config(written, where)
    if driver_name != "sim" and core.state_timeout_ns is None:
        raise where.at("timing").error(
            "missing required key 'state_timeout_ms': a real device needs the state watchdog "
            "(the arm stops when its state samples stop)")
    if driver_name != "sim" and core.collision is None:
        raise where.at("geometry").error(
            "missing required table: a real device needs the cell's geometry (the table, "
            "fixtures and keep-out zones its motions keep clear of)")
    emulator = _read(EmulatorSettings, doc, "emulator", where)
    driver_settings = decode_driver_settings(driver_name, driver, emulator.launch, where)
    policy = _policy(_read(PolicySettings, doc, "policy", where), where.at("policy"))
    check_cameras_travel(cameras, core.client.protocol, policy, where)
    cell = _read(CellSettings, doc, "cell", where)
    if cameras and cell.clock is ClockKind.VIRTUAL:
        raise where.at("cell").at("clock").error(
            "a virtual-clock run has no cameras: [[cameras]] see the cell on the wall clock")
    security = _policy_security(policy, where.at("policy"), credentials)
    _check_link_loss_first(core, policy, where)
    return Manifest(
        name=run_name(doc, path, where), path=path, core=core,
        sections=ScenarioSections.of(written),
        driver_name=driver_name, driver_settings=driver_settings, emulator=emulator,
        cell=cell,
        policy=policy, link_security=security,
        journal=_read(JournalSettings, doc, "journal", where),
        task=_task(doc, where, core),
        operator=_read(OperatorSettings, doc, "operator", where),
        safety=safety_table(doc, where, core.control_period_ns),
        trial=_trial(doc, where),
        cameras=cameras,
        metrics=_metrics(doc, where, cell),
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
            table(doc, section, where)
    check_keys(doc, where)
    for phase, body in table(doc, "phases", where).items():
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




def _policy(settings: PolicySettings, where: Where) -> PolicySettings:
    _policy_protocol(settings, where)
    if settings.latency_p95_ms < settings.latency_median_ms:
        raise where.at("latency_p95_ms").error(
            f"must be at least latency_median_ms ({settings.latency_median_ms:g}), got "
            f"{settings.latency_p95_ms:g}")
    if not settings.launch and settings.port == 0:
        raise where.at("port").error("must be the server's port (1 to 65535) with launch = "
                                     "false; 0 picks a free port only for a launched server")
    if not settings.host.strip():
        raise where.at("host").error("must not be empty")
    if settings.launch and not settings.expose and not is_loopback(settings.host):
        raise where.at("host").error(
            f"{settings.host!r} is not a loopback address: the reference server warden "
            "launches would take connections from other hosts (the link has no "
            "authentication). Use 127.0.0.1, or set policy.expose = true to mean it")
    return settings


def _policy_security(settings: PolicySettings, where: Where, read: bool) -> LinkSecurity:
    """``[policy.tls]`` and ``[policy.auth]`` checked now and, when ``read``, every file and
    the token read, so a run never starts to find them unusable."""
    for key in ("tls", "auth"):
        if settings.launch and getattr(settings, key) is not None:
            raise where.at(key).error(
                "only with launch = false: the reference server warden launches listens on "
                "loopback, without TLS or a token; start your policy server yourself and name "
                "its host and port")
    try:
        if not read:
            check_shape(settings)
            return LinkSecurity()
        return link_security(settings, Path(where.file).resolve().parent)
    except SecurityError as error:
        place = where
        for part in error.key.split("."):
            place = place.at(part)
        raise place.error(error.message) from None


def _policy_protocol(settings: PolicySettings, where: Where) -> None:
    openpi = settings.protocol is PolicyProtocol.OPENPI
    if openpi and settings.openpi is None:
        raise where.at("openpi").error('required with protocol = "openpi" (policy_checkpoint '
                                       "at least)")
    if not openpi and settings.openpi is not None:
        raise where.at("openpi").error('only with protocol = "openpi"')
    if openpi and settings.launch:
        raise where.at("launch").error('must be false with protocol = "openpi": warden '
                                       "launches only its reference server; start the openpi "
                                       "server yourself and name its port")


def is_loopback(host: str) -> bool:
    """``localhost`` or an address in 127.0.0.0/8 or ::1 (a name is not resolved: only
    ``localhost`` is known to stay on this host)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _read(cls: type, doc: Mapping[str, Any], key: str, where: Where) -> Any:
    return read_table(cls, table(doc, key, where), where.at(key))


def _task(doc: Mapping[str, Any], where: Where, core: CoreConfig) -> TaskSettings | None:
    if "task" not in doc:
        return None
    settings: TaskSettings = _read(TaskSettings, doc, "task", where)
    check_home(settings, core.limits, where.at("task"))
    return settings


def _metrics(doc: Mapping[str, Any], where: Where, cell: CellSettings) -> MetricsSettings | None:
    if "metrics" not in doc:
        return None
    settings: MetricsSettings = _read(MetricsSettings, doc, "metrics", where)
    if not is_loopback(settings.host):
        raise where.at("metrics").at("host").error(
            f"{settings.host!r} is not a loopback address: the endpoint has no authentication "
            "(put a scraper or a proxy on this host)")
    if cell.clock is ClockKind.VIRTUAL:
        raise where.at("metrics").error(
            "a virtual-clock run serves no live metrics (it ends in seconds; its summary has "
            "the same figures)")
    return settings


def _trial(doc: Mapping[str, Any], where: Where) -> TrialEnvelope | None:
    if "trial" not in doc:
        return None
    envelope: TrialEnvelope = _read(TrialEnvelope, doc, "trial", where)
    workspace_box(envelope.workspace_lower, envelope.workspace_upper, where.at("trial"),
                  ("workspace_lower", "workspace_upper"))
    return envelope
