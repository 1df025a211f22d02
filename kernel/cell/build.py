"""Put the cell together from a manifest: world, driver, core, skills, policy link.

Nothing here runs anything; :mod:`kernel.cell.lockstep` and :mod:`kernel.cell.live` do.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from assurance.handshake import HandshakeOffer
from assurance.kinematics import ArmKinematics
from drivers.base import CommandKind
from drivers.lifecycle import ManagedDriver
from kernel.cell.control import CellController
from kernel.cell.emulated import DeviceWorld, EmulatorWorld
from kernel.cell.motion import MotionController
from kernel.cell.operator import SimulatedOperator
from kernel.cell.world import SimWorld, World
from kernel.core.config import CoreConfig
from kernel.core.runtime import Core
from kernel.manifest import Manifest, ManifestError
from kernel.shell.gateway import CoreGateway
from kernel.shell.recorder import Recorder
from kernel.shell.timer import Clock
from skills.assembly import AssemblyRunner
from skills.contact import ContactOwner
from skills.evaluator import Evaluator
from skills.layout import CellLayout
from skills.planner import Planner
from skills.trajectory import MotionLimits
from stubs import robot_model as rm
from stubs.policy_server.policy import InsertionPolicy, LatencyModel

PLANNER_ACCELERATION = 6.0
PLANNER_JERK = 60.0
INTERPOLATOR_JERK = 50.0
POLICY_SPEED = 0.3
"""rad/s: how fast the scripted policy moves each joint toward its goal."""
POLICY_ACCELERATION = 3.0
"""rad/s²: how briskly the scripted policy speeds up and brakes."""


def cell_layout() -> CellLayout:
    return CellLayout(
        home_q=np.array(rm.HOME_Q), tool_down=np.array(rm.TOOL_DOWN_ROTATION),
        peg_start=np.array(rm.PEG_START_POSITION), hole_top=np.array(rm.HOLE_TOP_POSITION),
        peg_centre_below_tcp=rm.PEG_CENTRE_BELOW_TCP, peg_half_height=rm.PEG_HALF_EXTENTS[2],
        hole_depth=rm.HOLE_DEPTH, gripper_open=rm.GRIPPER_MAX_OPENING,
    )


@dataclass
class Cell:
    manifest: Manifest
    core: Core
    gateway: CoreGateway
    world: World
    driver: ManagedDriver
    controller: CellController
    kinematics: ArmKinematics
    layout: CellLayout
    policy_goal: np.ndarray


def build_cell(manifest: Manifest, clock: Clock, recorder: Recorder | None) -> Cell:
    config = dataclasses.replace(manifest.core, initial_session=None)  # handshake first
    world = _world(manifest, config.control_period_ns)
    try:
        return _assemble(manifest, config, world, clock, recorder)
    except BaseException:
        world.close()  # an emulator already started must not outlive a failed build
        raise


def _assemble(manifest: Manifest, config: CoreConfig, world: World, clock: Clock,
              recorder: Recorder | None) -> Cell:
    period = config.control_period_ns
    core = Core(config)
    gateway = CoreGateway(core, clock, recorder)
    kin = ArmKinematics()
    layout = cell_layout()
    arm_limits = config.limits
    planner_limits = MotionLimits(
        kin.lower, kin.upper, np.minimum(arm_limits.velocity[:6], 2.0),
        np.full(6, PLANNER_ACCELERATION), np.full(6, PLANNER_JERK))
    planner = Planner(kin, planner_limits, layout.tool_down)
    contact = ContactOwner(kin, layout.tool_down)
    runner = AssemblyRunner(layout, planner, contact,
                            Evaluator(manifest.cell.insertion_tolerance_m), world.insertion_depth)
    interpolator_limits = MotionLimits.from_joint_limits(arm_limits, INTERPOLATOR_JERK)
    impedance = CommandKind.IMPEDANCE in getattr(world.driver(), "capabilities", frozenset())
    motion = MotionController(interpolator_limits, layout.home_q, runner, contact, period,
                              impedance)
    driver = ManagedDriver(world.driver())
    operator = SimulatedOperator(enabled=manifest.cell.simulated_operator)
    controller = CellController(gateway, driver, world, runner, motion, operator,
                                manifest.cell.cycles)
    staging = planner.solve(layout.home_q, layout.staging_tcp)
    goal = planner.solve(staging, layout.pre_insert_tcp)
    return Cell(manifest, core, gateway, world, driver, controller, kin, layout, goal)


def _world(manifest: Manifest, period_ns: int) -> World:
    if manifest.driver_name == "sim":
        if manifest.driver_settings:
            key = next(iter(manifest.driver_settings))
            raise ManifestError(f"{manifest.path}: driver.{key}: unknown key (the sim driver "
                                "takes no settings)")
        return SimWorld(period_ns)
    if not manifest.emulator.launch:
        if manifest.cell.simulated_operator:
            raise ManifestError(f"{manifest.path}: cell.simulated_operator: must be false when "
                                "driving a real device (only a human accepts recovery)")
        return DeviceWorld(manifest)
    return EmulatorWorld(manifest)


def offer_for(manifest: Manifest) -> HandshakeOffer:
    """The reference server's offer: exactly what this manifest's session accepts."""
    session = manifest.sections["session"]
    return HandshakeOffer(
        policy_checkpoint=session["policy_checkpoint"], config_hash=session["config_hash"],
        observation_keys=tuple(session.get("observation_keys", ())),
        action_dim=int(session.get("action_dim", 6)),
        action_units=session.get("action_units", "rad"),
        action_frame=session.get("action_frame", "joint"),
        chunk_horizon=manifest.policy.chunk_horizon,
        protocol=tuple(session.get("protocol", (1, 1))), skill=session.get("skill"),
        skill_version=session["skill_version"], controller_mode=session["controller_mode"],
        calibration_epoch=str(session["calibration_epoch"]),
    )


def policy_model(manifest: Manifest, goal: np.ndarray) -> tuple[InsertionPolicy, LatencyModel]:
    settings = manifest.policy
    policy = InsertionPolicy(goal=goal, max_speed=POLICY_SPEED, noise_std=settings.noise_rad,
                             horizon=settings.chunk_horizon,
                             action_dt_s=settings.action_dt_ms / 1000.0,
                             max_acceleration=POLICY_ACCELERATION)
    return policy, LatencyModel(settings.latency_median_ms, settings.latency_p95_ms)
