"""The trial card: what bounds a trial and every way to stop it, each stop with its bound in
milliseconds, shown before a human confirms.

The bounds are the configured ones, from the moment the stop is due to the stop reaching the
device (docs/operations.md, "Stop bounds"); the arm's own stopping time comes on top of each.
"""

from __future__ import annotations

from pathlib import Path

from drivers import registry
from kernel.app.trial import arm_velocities, device_watchdog
from kernel.manifest import Manifest, ManifestError


def trial_card(manifest: Manifest, socket: Path, safety: str, journal: Path | None) -> str:
    """What is bounded, who can stop it and how fast, where the journal is."""
    envelope = manifest.trial
    if envelope is None:  # load_trial refuses such a manifest
        raise ManifestError(f"{manifest.path}: trial: missing")
    period_ms = manifest.core.control_period_ns / 1e6
    speed = (f"x{envelope.speed_scale:g}: at most "
             f"{', '.join(f'{v:.3g}' for v in arm_velocities(manifest))} rad/s")
    if envelope.speed_scale >= 1.0:
        speed += " (NOT reduced: the manifest's own limits, --full-speed)"
    rows = [
        ("trial", f"{manifest.name} ({manifest.path}, sha256 {manifest.digest[:16]}, signed "
                  f"by key {manifest.signer})"),
        ("cycles", f"at most {manifest.cell.cycles}"),
        ("duration", f"at most {envelope.max_duration_s:g} s"),
        ("joint speed", speed),
        ("tool workspace", f"{list(envelope.workspace_lower)} to "
                           f"{list(envelope.workspace_upper)} m (base frame): a setpoint "
                           "outside is never sent, a measured breach stops the arm within "
                           f"{period_ms:g} ms (the tick that measures it)"),
        ("wrist force", f"at most {envelope.max_wrist_force_n:g} N, or the arm stops within "
                        f"{period_ms:g} ms"),
        ("stop: a person", "the E-stop wired to the arm's safety system (hold it): its bound "
                           "is the arm's safety configuration's, not known to warden"),
        ("stop: operator", f"warden operator stop|takeover --socket {socket}: at the next "
                           f"control tick, within {period_ms:g} ms of the command's arrival "
                           "(the command line's own start-up comes before)"),
        ("stop: safety monitor", f"{safety}; within {_monitor_bounds(manifest)}"),
        ("stop: the device", _device_stop(manifest, period_ms)),
        ("journal", str(journal) if journal is not None else "none (--no-journal)"),
    ]
    width = max(len(name) for name, _ in rows)
    return "\n".join(f"{name:<{width}}  {text}" for name, text in rows)


def _monitor_bounds(manifest: Manifest) -> str:
    safety = manifest.safety
    if safety is None:  # safety_watching refuses such a manifest
        raise ManifestError(f"{manifest.path}: safety: missing")
    check = safety.check_period_ms
    return (f"{check:g} ms of a limit crossed, {safety.heartbeat_timeout_ms + check:g} ms of "
            "warden's last heartbeat (plus its stop path's answer)")


def _device_stop(manifest: Manifest, period_ms: float) -> str:
    text = device_watchdog(manifest)
    driver = registry.load(manifest.driver_name)
    bound = driver.device_watchdog_ms(manifest.driver_settings, period_ms)
    if bound is None:
        return f"{text} (its bound: not declared by the driver)"
    if bound == 0:
        return f"{text} (0 ms)"
    return f"{text}: {bound:g} ms after warden's last command"
