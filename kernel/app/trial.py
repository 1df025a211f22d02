"""``warden trial MANIFEST``: a bounded trial, started only when everything that bounds it holds.

In order, before anything moves:
1. the manifest's signature verifies, in this process, on the very bytes that are then parsed
   (read once, so what was signed is what runs);
2. it carries a trial envelope (``[trial]``: max cycles, max duration, a workspace box for the
   tool, a speed scale, a wrist force limit), the state watchdog, the robot model's digest (so
   the signature covers the model too), and no simulated operator;
3. the independent safety monitor answers that it is alive, connected and watching;
4. the trial card says what is bounded, who can stop it and how, and where the journal goes;
5. a human confirms: at the terminal (typing the run's name), or with
   ``warden operator confirm`` over the operator socket.
Then the cell runs with the envelope enforced: every joint's velocity limit is scaled down, the
core keeps the tool in the box and the wrist force under its limit (ENVELOPE stops the arm and
ends the trial), and the trial ends when its cycles are done or its duration is up, whichever
comes first, each with its reason. The journal's header records the manifest's digest, the key
that signed it, the software revision and the host.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec

from assurance.reasons import ReasonCode
from drivers import registry
from kernel import signing
from kernel.app.device import driver_from_manifest
from kernel.app.session import RunContext
from kernel.app.trial_limits import check_envelope
from kernel.config.build import build_config
from kernel.manifest import Manifest, ManifestError, TrialEnvelope, load_manifest
from kernel.model_file import model_spec
from kernel.robot_model import digest
from kernel.safety.status import ask
from kernel.scenario.fields import ScenarioError, Where
from kernel.sections import ScenarioSections

ENVELOPE_KEYS = ("max_cycles", "max_duration_s", "workspace_lower", "workspace_upper",
                 "speed_scale", "max_wrist_force_n")


def load_trial(path: Path, keys: Path, full_speed: bool = False) -> Manifest:
    """The manifest of a trial: verified, parsed from the verified bytes, with the envelope
    folded into what the core enforces (scaled velocity limits, the ``envelope`` section) and
    its cycles capped. ``full_speed``: a ``speed_scale`` of 1 is accepted (and logged).

    Raises:
        ManifestError: not signed by a trusted key, altered, no envelope, no watchdog, a
            simulated operator, an envelope wider than the arm's reach or the monitor's force
            limit, or one that reduces no speed (the message names the file and what is wrong).
    """
    try:
        verified = signing.verify(path, keys)
    except signing.SignatureError as error:
        raise ManifestError(f"{error} (a trial runs only from a manifest signed by a key in "
                            f"{keys})") from None
    manifest = load_manifest(path, content=verified.content, signer=verified.key_id)
    envelope = manifest.trial
    if envelope is None:
        raise ManifestError(f"{path}: trial: missing: a trial needs its envelope "
                            f"({', '.join(ENVELOPE_KEYS)})")
    if manifest.core.state_timeout_ns is None:
        raise ManifestError(f"{path}: timing.state_timeout_ms: missing: a trial needs the "
                            "state watchdog")
    device_watchdog(manifest)
    _signed_model(manifest)
    if manifest.cell.simulated_operator:
        raise ManifestError(f"{path}: cell.simulated_operator: must be false in a trial (only a "
                            "human accepts recovery)")
    bounded = _bounded(manifest, envelope)
    check_envelope(bounded, envelope, full_speed)
    return bounded


def _signed_model(manifest: Manifest) -> None:
    """The robot model is a file of its own: the signature covers it only through its digest,
    and the workspace box and the tool's pose are judged through it.

    Raises:
        ManifestError: a model without ``robot.model_sha256`` (the message gives the digest).
    """
    robot = manifest.sections.table("robot")
    where = Where(str(manifest.path), "robot")
    try:
        spec = model_spec(robot, where)
    except ScenarioError as error:
        raise ManifestError(str(error)) from None
    if spec is not None and robot.get("model_sha256") is None:
        kinematics = manifest.core.kinematics  # the digest of the bytes this run parsed
        sha256 = kinematics.config.sha256 if kinematics is not None else digest(spec.path)
        raise ManifestError(f"{manifest.path}: robot.model_sha256: missing: a trial's signature "
                            f"must cover the robot model {spec.path.name} too; add "
                            f'model_sha256 = "{sha256}" to [robot] and sign again')


def check_device_settings(manifest: Manifest) -> None:
    """A real device's driver settings, parsed as the run will (nothing is opened), so that
    a bad one is refused before anyone confirms.

    Raises:
        ManifestError: naming the ``[driver]`` key.
    """
    if manifest.driver_name != "sim" and not manifest.emulator.launch:
        driver_from_manifest(manifest)


def device_watchdog(manifest: Manifest) -> str:
    """What stops the arm if warden dies, as the driver's settings configure it.

    Raises:
        ManifestError: switched off, or a driver that declares none.
    """
    where = f"{manifest.path}: driver"
    try:
        driver = registry.load(manifest.driver_name)
    except registry.UnknownDriver as error:
        raise ManifestError(f"{where}.name: {error}") from None
    watchdog = driver.device_watchdog(manifest.driver_settings)
    if watchdog is None:
        raise ManifestError(f"{where}: a trial needs the device-side watchdog (it stops the arm "
                            f"when warden dies), and this {manifest.driver_name} table switches "
                            "it off or its driver declares none (docs/operations.md, "
                            "'Device-side watchdogs')")
    return str(watchdog)


def _bounded(manifest: Manifest, envelope: TrialEnvelope) -> Manifest:
    scenario = manifest.sections.document()
    robot = scenario["robot"]
    robot["velocity_limits"] = [round(v * envelope.speed_scale, 12) for v in
                                arm_velocities(manifest)]
    try:  # the velocities scaled, the envelope given typed (not read back from its section)
        core = build_config(scenario, Where(str(manifest.path), ""), envelope.bounds())
    except ScenarioError as error:
        raise ManifestError(str(error)) from None
    cell = msgspec.structs.replace(manifest.cell,
                                   cycles=min(manifest.cell.cycles, envelope.max_cycles))
    sections = ScenarioSections.of({**scenario,
                                   "envelope": msgspec.to_builtins(envelope.section())})
    return dataclasses.replace(manifest, core=core, sections=sections, cell=cell)


def arm_velocities(manifest: Manifest) -> list[float]:
    limits = manifest.core.limits
    return [float(v) for v, arm in zip(limits.velocity, limits.arm_mask, strict=True) if arm]


@dataclass
class TrialBound:
    """Ends a running trial when a bound is reached (the live run's tick hook)."""

    duration_s: float
    reason: str = ""

    def __call__(self, context: RunContext) -> bool:
        if context.cell.core.status().cause is ReasonCode.ENVELOPE:
            self.reason = "the envelope was reached (ENVELOPE): the arm stopped"
        elif context.heartbeat is not None and context.heartbeat.last_error is not None:
            self.reason = (f"the safety monitor stopped taking warden's heartbeat "
                           f"({context.heartbeat.last_error}): the trial is no longer watched")
        elif context.cell.gateway.now_ns() * 1e-9 >= self.duration_s:
            self.reason = f"the trial's duration is up ({self.duration_s:g} s)"
        return bool(self.reason)


def verdict(summary: dict[str, Any], bound: TrialBound, planned: int) -> tuple[int, str]:
    """The trial's exit code and why: 0 only when all ``planned`` cycles ran and verified and
    nothing ended the trial early, 1 otherwise. A cycle under way when the trial ended (a
    bound, a signal, the run's time budget, a failed task) is counted as unfinished: the
    summary's ``cycles`` lists finished cycles only, so ``summary["trial"]["cycles"]`` (see
    :func:`cycle_count`) says what happened to each of the ``planned``."""
    counts = cycle_count(summary, planned)
    early = bound.reason or (_ended_early(summary) if counts["finished"] < planned else "")
    tally = (f"{counts['verified']} of {planned} cycles verified"
             + (f", cycle {counts['finished'] + 1} unfinished" if counts["unfinished"] else "")
             + (f", {counts['not_started']} not started" if counts["not_started"] else ""))
    if early:
        return 1, f"ended: {early}; {tally}"
    return (0 if counts["verified"] == planned else 1), f"ended: {tally}"


def cycle_count(summary: dict[str, Any], planned: int) -> dict[str, int]:
    """Of the ``planned`` cycles: how many finished, verified, were under way when the run
    ended (at most one: cycles run one after another), and never started. A run that lists
    the cycle it cut short among its cycles says which (``cycle_cut_short``); otherwise the
    cycles listed are the finished ones, and one was under way if the loop ticked at all."""
    listed = len(summary["cycles"]["detail"])
    if "cycle_cut_short" in summary:
        under_way = int(summary["cycle_cut_short"] is not None)
        finished = listed - under_way
    else:
        finished = listed
        under_way = int(finished < planned and summary.get("ticks", 0) > 0)
    return {"planned": planned, "finished": finished,
            "verified": summary["cycles"]["verified"], "unfinished": under_way,
            "not_started": planned - finished - under_way}


def _ended_early(summary: dict[str, Any]) -> str:
    """Why the run ended before its cycles were done, as the live run's summary says (a
    policy link that failed and was restarted is in ``task_failures`` too, but did not end
    the run: this is asked only when cycles are missing)."""
    if summary.get("stopped"):
        signal_name = summary.get("interrupted") or "SIGINT or SIGTERM"
        return f"interrupted ({signal_name}): the arm was held and the device closed"
    if (summary.get("journal") or {}).get("error"):
        return "the run's record could not be written"
    if summary.get("task_failures"):
        return f"a task failed ({'; '.join(summary['task_failures'])})"
    if summary.get("timed_out"):
        return "timed out: the run's time budget (cycles x cell.cycle_timeout_s) ran out"
    return ""


def safety_watching(manifest: Manifest, timeout_s: float = 2.0) -> str:
    """Asks the independent safety monitor, live, whether it watches this very cell; what it
    watches and how it stops the arm, for the card.

    Raises:
        ManifestError: no ``[safety]`` table; no monitor answers; it is not alive, connected
            and watching; it watches another manifest (another digest: other limits); or it
            cannot stop the arm (a trial needs a stop layer outside warden besides the
            device's own watchdog).
    """
    settings = manifest.safety
    where = f"{manifest.path}: safety"
    if settings is None:
        raise ManifestError(f"{where}: missing: a trial needs the safety monitor "
                            "([safety], and `warden safety MANIFEST` running)")
    path = settings.status_path
    try:
        answer = ask(path, timeout_s)
    except (OSError, ValueError) as error:
        raise ManifestError(f"{where}.status_socket: no safety monitor answers at {path} "
                            f"({error}); start it: warden safety {manifest.path}") from None
    if not answer.get("ok"):
        problems = "; ".join(str(p) for p in answer.get("problems") or ["not ok"])
        raise ManifestError(f"{where}: the safety monitor is not ok: {problems}")
    watched = answer.get("manifest") or {}
    if watched.get("digest") != manifest.digest:
        raise ManifestError(
            f"{where}: the safety monitor watches {watched.get('path', 'another manifest')} "
            f"(sha256 {str(watched.get('digest'))[:16]}), not this manifest "
            f"(sha256 {manifest.digest[:16]}): it would check other limits")
    if not answer.get("can_stop"):
        raise ManifestError(f"{where}: the safety monitor cannot stop this arm "
                            f"({answer.get('stop_path')}); a trial needs one that can")
    return f"{answer.get('device')}; stops via {answer.get('stop_path')} (warden safety status)"

