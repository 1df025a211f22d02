"""The cell through a real vendor driver: the device is an emulator process with the MuJoCo
plant behind it, reached over the driver's real transport.

One launcher per driver name says how to start that driver's emulator and which settings the
driver then needs (the emulator's address); everything else comes from the manifest's
``[driver]`` table. The evaluator's ground truth and the parts feeder go over the emulator's
test-only control port (see :mod:`stubs.plant.world_port`), never over the robot protocol.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import msgspec

from drivers.base import Driver, DriverInitError
from kernel.app.device import driver_from_manifest
from kernel.manifest import Manifest, ManifestError
from stubs.fault_control import inject
from stubs.process import EmulatorProcess, EmulatorStartError


@dataclass(frozen=True, slots=True)
class Launch:
    module: str
    args: tuple[str, ...]
    settings: Callable[[Mapping[str, Any]], dict[str, Any]]
    """Driver settings that depend on the emulator's READY information."""
    control_host: Callable[[Mapping[str, Any]], str]


def _ur(manifest: Manifest, plant: str) -> Launch:
    from stubs.ur_controller.launch import free_loopback_host

    host = manifest.emulator.host or free_loopback_host()
    args = ("--host", host, "--plant", plant, *_ur_gripper_flags(manifest))
    return Launch("stubs.ur_controller", args,
                  lambda ready: {"host": ready["host"]}, lambda ready: ready["host"])


def _ur_gripper_flags(manifest: Manifest) -> tuple[str, ...]:
    """The gripper's wiring for the emulated controller (the settings were checked already);
    its signal is fixed there (0-10 V over the stroke), so a manifest must agree with it."""
    from stubs.ur_controller.io_board import GripperWiring

    settings = manifest.driver_settings
    if settings.gripper_output is None:
        return ()
    emulated = GripperWiring()
    for key, given, value in (
            ("gripper_feedback_closed", settings.gripper_feedback_closed, 0.0),
            ("gripper_feedback_open", settings.gripper_feedback_open, emulated.full_scale_v),
            ("gripper_max_opening_m", settings.gripper_max_opening_m, emulated.max_opening_m)):
        if given != value:
            raise ManifestError(f"{manifest.path}: driver.{key}: the emulated controller's "
                                f"gripper reads {value} here; set it so, or drop the key")
    feedback = settings.gripper_feedback
    return ("--gripper-output", str(settings.gripper_output),
            "--gripper-feedback-input", feedback.removeprefix("standard_analog_input"))


def _dynamixel(manifest: Manifest, plant: str) -> Launch:
    settings = manifest.driver_settings
    args = ("--ids", ",".join(map(str, settings.ids)), "--baud", str(settings.baud),
            "--plant", plant, *_flags({"--gripper-id": settings.gripper_id}))
    if settings.gripper_id is not None:
        args += ("--gripper-open-ticks", str(settings.gripper_open_ticks),
                 "--gripper-closed-ticks", str(settings.gripper_closed_ticks))
    return Launch("stubs.dynamixel_bus", args, lambda ready: {"port": ready["port"]},
                  lambda _: "127.0.0.1")


def _flags(flags: Mapping[str, Any]) -> tuple[str, ...]:
    """Emulator flags for the driver settings the manifest sets (the device's build: what a
    real bus or cell would have wired)."""
    return tuple(part for flag, value in flags.items() if value is not None
                 for part in (flag, str(value)))


def _canopen(manifest: Manifest, plant: str) -> Launch:
    from stubs.cia402_drive.launch import unique_udp_bus

    group, port = unique_udp_bus()
    settings = manifest.driver_settings
    nodes = settings.node_ids
    args = ("--channel", group, "--port", str(port), "--nodes", ",".join(map(str, nodes)),
            "--counts-per-rev", str(int(settings.counts_per_rev[0])), "--plant", plant,
            *_flags({"--gripper-node": settings.gripper_node}))
    if settings.gripper_node is not None:
        args += ("--gripper-counts-per-m", str(settings.gripper_counts_per_m))
    return Launch("stubs.cia402_drive", args,
                  lambda ready: {"interface": "udp_multicast", "channel": ready["channel"],
                                 "udp_port": ready["port"]}, lambda _: "127.0.0.1")


LAUNCHERS: dict[str, Callable[[Manifest, str], Launch]] = {
    "ur_rtde": _ur,
    "dynamixel": _dynamixel,
    "canopen402": _canopen,
}


class EmulatorWorld:
    """A vendor driver's emulator process with the MuJoCo plant behind it (the
    ``warden.worlds`` entry point of ``ur_rtde``, ``dynamixel`` and ``canopen402``)."""

    has_ground_truth = True

    def __init__(self, manifest: Manifest) -> None:
        launcher = LAUNCHERS.get(manifest.driver_name)
        if launcher is None:
            raise ManifestError(f"{manifest.path}: driver.name: no emulator for "
                                f"{manifest.driver_name!r} (known: {', '.join(LAUNCHERS)})")
        # The settings were checked when the manifest was loaded, with the driver's placeholders
        # for the emulator's address: a mistake was named by key before any process starts.
        plant = str(manifest.emulator.plant)
        launch = launcher(manifest, plant)
        try:
            self.process = EmulatorProcess(launch.module, *launch.args).start()
        except EmulatorStartError as error:
            raise DriverInitError(manifest.driver_name, f"{error}; its own message is above"
                                  ) from None
        ready = self.process.info
        port = ready.get("control_port", ready.get("fault_port"))
        self.control = (launch.control_host(ready), int(port))
        settings = msgspec.structs.replace(manifest.driver_settings, **launch.settings(ready))
        try:
            self._driver = driver_from_manifest(manifest, settings)
        except ManifestError:
            self.process.stop()
            raise

    def driver(self) -> Driver:
        return self._driver

    def advance(self) -> None:
        """The emulator steps its own plant in real time."""

    def insertion_depth(self) -> float:
        return float(inject(self.control, "ground_truth")["insertion_depth"])

    def feed_part(self) -> None:
        inject(self.control, "feed_peg")

    def inject(self, fault: str, **fields: Any) -> dict[str, Any]:
        """Switch an emulated device fault on (tests and fault campaigns)."""
        return inject(self.control, fault, **fields)

    def close(self) -> None:
        self.process.stop()
