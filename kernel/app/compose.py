"""The one composition root: a manifest in, a cell ready to run out.

It picks the world (a real device through the driver registry; in simulation, the stand-in
the manifest's driver names through :mod:`kernel.app.standins`), fixes the core's configuration
for it, and wires the core, the gateway, the driver's lifecycle, the task and the control loop.
Nothing here runs anything: :mod:`kernel.app.lockstep` and :mod:`kernel.app.live` do.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from drivers import registry
from drivers.base import CommandKind
from drivers.lifecycle import ManagedDriver
from kernel.app import standins
from kernel.app.context import CellContext
from kernel.app.control import ControlLoop
from kernel.app.device import DeviceWorld, World
from kernel.app.task import assembly_runner
from kernel.core.config import CoreConfig
from kernel.core.runtime import Core
from kernel.manifest import Manifest, ManifestError
from kernel.model_file import model_spec
from kernel.scenario.fields import Where
from kernel.sections import ScenarioSections
from kernel.shell.gateway import CoreGateway
from kernel.shell.recorder import Recorder
from kernel.shell.timer import Clock, MonotonicClock
from skills.planner import Planner


@dataclass
class Cell:
    manifest: Manifest
    core: Core
    gateway: CoreGateway
    world: World
    driver: ManagedDriver
    controller: ControlLoop
    context: CellContext
    real_device: bool
    """A device, not a simulated world: only a human recovers it (through the operator
    socket)."""


def world_for(manifest: Manifest) -> World:
    """The device (a real one, with no stand-in involved) or the simulated world.

    Raises:
        ManifestError: a simulated world that is not installed, or a real device with the
            simulated operator on.
    """
    name = manifest.driver_name
    where = f"{manifest.path}: driver.name"
    if name not in registry.available():
        known = ", ".join(sorted(registry.available()))
        raise ManifestError(f"{where}: unknown driver {name!r}; known drivers: {known}")
    if name != "sim" and not manifest.emulator.launch:
        if manifest.cell.simulated_operator:
            raise ManifestError(f"{manifest.path}: cell.simulated_operator: must be false when "
                                "driving a real device (only a human accepts recovery)")
        return DeviceWorld(manifest)
    try:
        factory = standins.load(standins.WORLDS, name)
    except ManifestError as error:
        raise ManifestError(f"{where}: no simulated world for {name!r} ({error})") from None
    return factory(manifest)


def effective(manifest: Manifest, world: World) -> tuple[CoreConfig, ScenarioSections]:
    """The core's configuration for this world, and the sections a journal must carry to
    rebuild exactly it: the device's impedance capability, the model file's path and digest."""
    impedance = manifest.core.motion.impedance and CommandKind.IMPEDANCE in world.driver(
        ).capabilities
    motion = dataclasses.replace(manifest.core.motion, impedance=impedance)
    config = dataclasses.replace(manifest.core, initial_session=None, motion=motion)
    sections = manifest.sections.document()
    sections["motion"] = {**sections.get("motion", {}), "impedance": impedance}
    spec = model_spec(sections["robot"], Where(str(manifest.path), "robot"))
    kinematics = manifest.core.kinematics
    if spec is not None and kinematics is not None:
        robot = {key: value for key, value in sections["robot"].items() if key != "kinematics"}
        # The digest of the bytes the run's model was parsed from, never a second read of a
        # file that may have changed since.
        sections["robot"] = {**robot, "model": str(spec.path), "tcp_frame": spec.tcp_frame,
                             "model_sha256": kinematics.config.sha256}
        if spec.joints is not None:
            sections["robot"]["joints"] = list(spec.joints)
    return config, ScenarioSections.of(sections)


def build_cell(manifest: Manifest, config: CoreConfig, world: World, clock: Clock,
               recorder: Recorder | None) -> Cell:
    kinematics = config.kinematics
    if kinematics is None:
        raise ManifestError(f"{manifest.path}: robot: the assembly task needs the arm's model "
                            "('kinematics' or 'model')")
    core = Core(config)
    gateway = CoreGateway(core, clock, recorder)
    limits = core.planner_limits
    truth = world.insertion_depth if world.has_ground_truth and manifest.cell.ground_truth \
        else None
    runner = assembly_runner(manifest, kinematics, limits, truth)
    operator = None
    if manifest.cell.simulated_operator:
        operator = standins.load(standins.OPERATORS, "simulated")()
    driver = ManagedDriver(world.driver())
    controller = ControlLoop(gateway, driver, world, runner, operator, manifest.cell.cycles)
    planner = Planner(kinematics, limits, runner.layout.tool_down)
    context = CellContext(manifest, runner.layout, planner, kinematics, gateway)
    return Cell(manifest, core, gateway, world, driver, controller, context,
                isinstance(world, DeviceWorld))


def cell_context(manifest: Manifest) -> CellContext:
    """What a stand-in needs of a cell that is not built (``warden serve-policy``): the task's
    layout and the arm's model, exactly as :func:`build_cell` makes them.

    Raises:
        ManifestError: the manifest has no arm model, or its task does not fit the arm.
    """
    kinematics = manifest.core.kinematics
    if kinematics is None:
        raise ManifestError(f"{manifest.path}: robot: the assembly task needs the arm's model "
                            "('kinematics' or 'model')")
    core = Core(manifest.core)
    limits = core.planner_limits
    runner = assembly_runner(manifest, kinematics, limits, None)
    planner = Planner(kinematics, limits, runner.layout.tool_down)
    return CellContext(manifest, runner.layout, planner, kinematics,
                       CoreGateway(core, MonotonicClock()))


def source_of(manifest: Manifest) -> str:
    """The file a worker rebuilds the configuration from (relative paths resolve against it)."""
    return str(Path(manifest.path).resolve())
