"""``warden check MANIFEST``: the device brought up as a run brings it up, watched while it holds
on its own, and compared with the manifest, without a single motion command.

In order, each step one or more rows of the readiness table:

1. the manifest's signature, verified in this process on the very bytes then parsed (an
   unsigned manifest is checked all the same: its signature row is NOT READY);
2. connect, configure, activate: the driver's own hooks, in the order and with the limits a run
   uses (:func:`kernel.app.session.control_config`). Activation leaves every device holding
   where it is with its own position loop, with no command: a UR controller idles with its
   control script running, Dynamixel servos get goal := present position before torque on,
   CiA 402 drives target := actual before they are enabled;
3. watch: read the device once per control period for ``seconds``: samples arrive without a
   fault, every joint is inside the manifest's limits, the arm stays where it is;
4. inspect: the driver's own comparison of the device's modes, limits and calibration with the
   manifest (``Driver.inspect``), reads only;
5. deactivate, close;
6. the policy server, reached as a run reaches it, without a session
   (:mod:`kernel.app.check_policy`);
7. each camera, read for a moment (:mod:`kernel.app.check_cameras`).

The driver's ``write`` and ``hold`` are never called: a hold is a setpoint to a streaming
device (servoJ to the measured position, goal := present with torque on), which the device
counts as motion. A device that cannot be reached or identified at connect ends the check with
the driver's error (the CLI exits 2); a device that answers and reports a fault is a NOT READY
row.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Sequence
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

from drivers.base import ControlConfig, DeviceFault, Driver, DriverError, StateSample
from drivers.readiness import CheckVerdict, Finding, judged, not_exercised, span
from kernel import signing
from kernel.app.check_cameras import camera_rows
from kernel.app.check_policy import policy_rows
from kernel.app.compose import world_for
from kernel.app.device import World
from kernel.app.session import control_config
from kernel.manifest import Manifest, ManifestError, load_manifest

SECONDS_RANGE = (0.1, 600.0)
DRIFT_RAD = 0.01
"""A joint whose measured position spans more than this while the device holds it moved."""
STEPS = {
    "connect": "reached and identified",
    "configure": "takes the manifest's control period and limits",
    "activate": "enabled, holding where it is",
    "deactivate": "disabled without moving",
    "close": "released",
}
"""What each lifecycle step of the driver must do, as the table says it."""


@dataclass(frozen=True, slots=True)
class Report:
    manifest: Manifest
    device: str
    findings: tuple[Finding, ...]

    @property
    def exit_code(self) -> int:
        """0: nothing NOT READY (a NOT EXERCISED row says what check cannot try); 1 otherwise."""
        return 1 if any(f.verdict is CheckVerdict.NOT_READY for f in self.findings) else 0


def load_checked(path: Path, keys: Path) -> tuple[Manifest, Finding]:
    """The manifest, parsed from the bytes its signature was verified on, and the signature's
    row.

    Raises:
        ManifestError: the manifest cannot be used, or it has a signature that does not verify
            against the keys in ``keys`` (nothing has started).
    """
    expected = f"signed by a trusted key in {keys}"
    try:
        verified = signing.verify(path, keys)
    except signing.Unsigned as error:
        manifest = load_manifest(path)
        return manifest, Finding(name="manifest signature", expected=expected,
                                 measured="no signature file", verdict=CheckVerdict.NOT_READY,
                                 reason=f"{error}; `warden trial` refuses it")
    except signing.SignatureError as error:
        raise ManifestError(f"{error} (check verifies a signature whenever there is one)"
                            ) from error
    manifest = load_manifest(path, content=verified.content, signer=verified.key_id)
    return manifest, judged("manifest signature", expected,
                            f"key {verified.key_id} ({verified.key_path.name})", [])


def run_check(manifest: Manifest, signature: Finding, seconds: float) -> Report:
    """Start the world (the device, or its stand-in in simulation), check it, close it.

    Raises:
        ManifestError: ``seconds`` out of range, or a world the manifest cannot have.
        DriverError: the device cannot be reached or identified.
    """
    low, high = SECONDS_RANGE
    if not low <= seconds <= high:
        raise ManifestError(f"--seconds: must be {low:g} to {high:g}, got {seconds:g}")
    from kernel.shell.loop import run

    world = world_for(manifest)
    try:
        findings = run(check_device(manifest, world, seconds))
    finally:
        world.close()
    return Report(manifest, manifest.driver_name, (signature, *findings))


async def check_device(manifest: Manifest, world: World, seconds: float) -> list[Finding]:
    """Every device row, in order (the driver is closed whatever happens).

    Raises:
        DriverError: the device cannot be reached or identified at connect.
    """
    driver = world.driver()
    control = control_config(manifest.core)
    rows: list[Finding] = []
    try:
        if await _connected(driver, rows) and await _step(
                rows, "configure", driver.configure(control)) and await _step(
                rows, "activate", driver.activate()):
            rows += await _watch(driver, world, control, seconds)
            rows += await _inspected(driver)
            await _step(rows, "deactivate", driver.deactivate())
    finally:
        await _step(rows, "close", driver.aclose())
    return rows + await policy_rows(manifest) + await camera_rows(manifest) + _not_exercised()


async def _connected(driver: Driver, rows: list[Finding]) -> bool:
    """Connect; a device that answers with a fault is a row, anything else ends the check."""
    try:
        await driver.connect()
    except DeviceFault as error:
        rows.append(_step_row("connect", error))
        return False
    rows.append(_step_row("connect", None))
    return True


async def _step(rows: list[Finding], name: str, call: Awaitable[None]) -> bool:
    try:
        await call
    except DriverError as error:
        rows.append(_step_row(name, error))
        return False
    rows.append(_step_row(name, None))
    return True


def _step_row(name: str, error: DriverError | None) -> Finding:
    return judged(f"device: {name}", STEPS[name], "done" if error is None else "failed",
                  [] if error is None else [str(error)])


async def _watch(driver: Driver, world: World, control: ControlConfig,
                 seconds: float) -> list[Finding]:
    """Read once per control period (stepping in-process physics as a run does)."""
    period_s = control.period_ns * 1e-9
    samples: list[StateSample] = []
    failure: DriverError | None = None
    started = next_read = time.monotonic()
    while time.monotonic() - started < seconds:
        try:
            samples.append(await driver.read())
        except DriverError as error:
            failure = error
            break
        world.advance()
        next_read += period_s
        await asyncio.sleep(max(0.0, next_read - time.monotonic()))
    return [_samples_row(samples, failure, period_s, seconds), _limits_row(samples, control),
            _rest_row(samples)]


def _samples_row(samples: Sequence[StateSample], failure: DriverError | None, period_s: float,
                 seconds: float) -> Finding:
    gaps = [(b.t_mono_ns - a.t_mono_ns) * 1e-6 for a, b in pairwise(samples)]
    measured = f"{len(samples)} samples, longest gap {max(gaps, default=0.0):.0f} ms"
    problems = [f"after {len(samples)} samples: {failure}"] if failure else []
    if not samples and not failure:
        problems.append("no sample")
    return judged("state samples", f"one per control period ({period_s * 1e3:g} ms) for "
                  f"{seconds:g} s, no device fault", measured, problems)


def _limits_row(samples: Sequence[StateSample], control: ControlConfig) -> Finding:
    expected = "inside the manifest's limits: " + ", ".join(
        f"[{low:.3f}, {high:.3f}]" for low, high in zip(control.q_lower, control.q_upper,
                                                        strict=True)) + " rad"
    if not samples:
        return not_exercised("joint positions", expected, "no sample was read")
    problems = []
    for joint, (low, high) in enumerate(zip(control.q_lower, control.q_upper, strict=True)):
        values = [sample.q[joint] for sample in samples if len(sample.q) > joint]
        if len(values) < len(samples):
            problems.append(f"joint {joint}: missing from the samples (the device reports "
                            f"{len(samples[-1].q)} joints)")
        elif not all(low <= v <= high for v in values):
            where = f"{min(values):.3f}" + (f" to {max(values):.3f}" if max(values) > min(
                values) else "")
            problems.append(f"joint {joint}: at {where} rad, outside [{low:.3f}, {high:.3f}]: "
                            "a run would start outside the limits it enforces")
    return judged("joint positions", expected, f"{span(samples[-1].q)} rad", problems)


def _rest_row(samples: Sequence[StateSample]) -> Finding:
    expected = f"every joint within {DRIFT_RAD} rad of where it was"
    if not samples:
        return not_exercised("at rest while held", expected, "no sample was read")
    drift = [max(column) - min(column) for column in zip(*(s.q for s in samples), strict=False)]
    speed = max((abs(v) for s in samples for v in s.qd), default=0.0)
    moved = [f"joint {joint} moved {d:.3g} rad" for joint, d in enumerate(drift)
             if d > DRIFT_RAD]
    if moved:
        moved.append("the device does not hold the arm where it is (brakes, gains, load)")
    return judged("at rest while held", expected,
                  f"largest drift {max(drift, default=0.0):.2g} rad, largest speed "
                  f"{speed:.2g} rad/s", moved)


async def _inspected(driver: Driver) -> tuple[Finding, ...]:
    name, expected = "device configuration", "modes, limits and calibration as the manifest says"
    try:
        findings = await driver.inspect()
    except DriverError as error:
        return (judged(name, expected, "could not be read", [str(error)]),)
    if findings is None:
        return (not_exercised(name, expected,
                              f"the driver {driver.name!r} offers no inspection"),)
    return findings


def _not_exercised() -> list[Finding]:
    return [
        not_exercised("motion", "setpoints followed inside the manifest's limits",
                      "check sends no setpoint, hold, stop or gripper command", "0 commands"),
    ]

