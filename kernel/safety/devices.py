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

from kernel.safety.checks import Sample
from kernel.safety.settings import SafetySettings
from kernel.safety.view import MonitorView
from kernel.safety.watch import DeviceUnreachable, DeviceWatch, StopResult


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


def _dynamixel(manifest: MonitorView, settings: SafetySettings) -> DeviceWatch:
    port = manifest.driver_settings.port
    return HeartbeatOnly(
        f"dynamixel bus on {port} (single master: warden; no second connection)",
        "the servos' Bus Watchdog (register 98, armed by the driver) stops each servo when "
        "warden's packets stop; the monitor reports only")


def _canopen(manifest: MonitorView, settings: SafetySettings) -> DeviceWatch:
    from kernel.safety.canopen import CiA402Watch  # imports canopen: only for a CiA 402 cell

    return CiA402Watch.from_manifest(manifest, settings)


def _ur(manifest: MonitorView, settings: SafetySettings) -> DeviceWatch:
    from kernel.safety.ur import URWatch  # imports ur_rtde: only for a UR cell

    return URWatch.from_manifest(manifest, settings)


def _sim(manifest: MonitorView, settings: SafetySettings) -> DeviceWatch:
    from kernel.safety.sim import SimWorldWatch

    return SimWorldWatch.from_manifest(manifest, settings)


WATCHES: dict[str, Callable[[MonitorView, SafetySettings], DeviceWatch]] = {
    "ur_rtde": _ur,
    "sim": _sim,
    "dynamixel": _dynamixel,
    "canopen402": _canopen,
}


def watch_for(manifest: MonitorView, settings: SafetySettings) -> DeviceWatch:
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
