"""The monitor's own view of each kind of device, and its own way to stop the arm.

A :class:`DeviceWatch` is the monitor's second connection to the device (where the device
allows one) and its stop path. One per driver name (:data:`WATCHES`):

- ``ur_rtde``: a second RTDE receive session (ur_rtde's ``RTDEReceiveInterface``) and the
  dashboard server's ``stop`` (:mod:`kernel.safety.ur`);
- ``sim``: the simulated world's test-only control port: its ground truth and a brake
  (:mod:`kernel.safety.sim`);
- ``dynamixel``: none. A serial bus has one master, and that is warden; the servos' own Bus
  Watchdog is the stop path, and the monitor only watches warden's heartbeat and reports
  (:class:`HeartbeatOnly`);
- ``canopen402``: a listening node of its own on the drives' CAN bus (their TPDOs, heartbeats
  and EMCYs) and NMT *Stop remote node* to each drive (:mod:`kernel.safety.canopen`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from kernel.manifest import Manifest
from kernel.safety.checks import Sample
from kernel.safety.settings import SafetySettings


class DeviceUnreachable(Exception):
    """The monitor cannot watch this device (at start: exit 2); the message says what to
    check."""


class DeviceLost(Exception):
    """The monitor's view of the device went stale or stopped answering (a breach)."""


@dataclass(frozen=True, slots=True)
class StopResult:
    done: bool
    detail: str
    """The device's answer, or why the stop could not be delivered."""


class DeviceWatch(Protocol):
    description: str
    """The device and the monitor's connection to it, for logs and status."""
    stop_path: str
    """How this monitor stops the arm, or why it cannot."""
    can_stop: bool
    lives_in_warden: bool
    """The device exists only inside warden's process (the simulated world): with no warden
    run it is gone, and nothing can move."""

    def connect(self) -> None:
        """Open the connection and check the stop path answers.

        Raises:
            DeviceUnreachable: either cannot be reached; nothing was commanded.
        """
        ...

    def sample(self) -> Sample | None:
        """The newest reading; None: nothing to read now (a watch that reads no device, or CiA
        402 drives that exchange no process data). A watch that can stop must read while warden
        runs: the monitor counts None for longer than ``device_timeout_ms`` while warden's
        heartbeat is alive as the device lost, unless it stopped the device in that run.

        Raises:
            DeviceLost: no fresh data within ``device_timeout_ms``, or the link is down.
        """
        ...

    def stop(self) -> StopResult:
        """Stop the arm through the monitor's own path; never raises."""
        ...

    def probe(self) -> str | None:
        """Check that the stop path still answers (called about once a second while nothing
        is wrong); the problem, or None. May reconnect."""
        ...

    def reconnect(self) -> bool:
        """After a :class:`DeviceLost`: try once, with a short deadline; True if back."""
        ...

    def close(self) -> None: ...


class HeartbeatOnly:
    """A device the monitor cannot open a second connection to (a single-master bus)."""

    can_stop = False
    lives_in_warden = False

    def __init__(self, description: str, stop_path: str) -> None:
        self.description, self.stop_path = description, stop_path

    def connect(self) -> None:
        """Nothing to open."""

    def sample(self) -> Sample | None:
        return None

    def stop(self) -> StopResult:
        return StopResult(False, f"this monitor cannot stop the arm: {self.stop_path}")

    def probe(self) -> str | None:
        return None

    def reconnect(self) -> bool:
        return True

    def close(self) -> None:
        """Nothing to close."""


def _dynamixel(manifest: Manifest, settings: SafetySettings) -> DeviceWatch:
    port = manifest.driver_settings.port
    return HeartbeatOnly(
        f"dynamixel bus on {port} (single master: warden; no second connection)",
        "the servos' Bus Watchdog (register 98, armed by the driver) stops each servo when "
        "warden's packets stop; the monitor reports only")


def _canopen(manifest: Manifest, settings: SafetySettings) -> DeviceWatch:
    from kernel.safety.canopen import CiA402Watch  # imports canopen: only for a CiA 402 cell

    return CiA402Watch.from_manifest(manifest, settings)


def _ur(manifest: Manifest, settings: SafetySettings) -> DeviceWatch:
    from kernel.safety.ur import URWatch  # imports ur_rtde: only for a UR cell

    return URWatch.from_manifest(manifest, settings)


def _sim(manifest: Manifest, settings: SafetySettings) -> DeviceWatch:
    from kernel.safety.sim import SimWorldWatch

    return SimWorldWatch.from_manifest(manifest, settings)


WATCHES: dict[str, Callable[[Manifest, SafetySettings], DeviceWatch]] = {
    "ur_rtde": _ur,
    "sim": _sim,
    "dynamixel": _dynamixel,
    "canopen402": _canopen,
}


def watch_for(manifest: Manifest, settings: SafetySettings) -> DeviceWatch:
    """The watch for the manifest's driver (not yet connected).

    Raises:
        DeviceUnreachable: no watch exists for this driver, or its settings cannot name the
            device.
    """
    factory = WATCHES.get(manifest.driver_name)
    if factory is None:
        raise DeviceUnreachable(f"{manifest.path}: driver.name: the safety monitor knows no "
                                f"{manifest.driver_name!r} device (known: {', '.join(WATCHES)})")
    return factory(manifest, settings)
