"""A bus of emulated CiA 402 drives, one per joint and optionally one for the gripper, all
moving one plant.

On every SYNC the emulator applies the RPDOs received since the last one, commands the plant
(each enabled CSP drive's target; everything else held where it stopped), steps the plant by the
wall time since the previous SYNC (capped, so a pause in SYNC is not a jump), and answers with
the TPDOs. The gripper drive is a drive like the others (NMT, SDO, PDOs, 402 states, heartbeat,
EMCY, fault injection by node id); only its link to the plant differs (``gripper.py``).

The drives also keep their own time, as a drive's firmware does whatever the bus does: a clock
thread checks every drive's heartbeat consumer each millisecond, and once SYNC is late it steps
the plant itself with the drives' last targets (a motor does not freeze when its master stops
talking; without this, a dead master would freeze the emulated arm mid-motion). A consumer is
judged only while no received frame waits in the bus's socket: a real drive's CAN controller
takes a frame in as it arrives, this process may be behind (a busy core) with the heartbeat
among the frames it has not read yet.
Frames are handled on canopen's notifier thread; one lock orders them, the clock and fault
injection. In-process on ``virtual``; across processes on ``udp_multicast`` (``__main__``).
"""

from __future__ import annotations

import logging
import math
import select
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import can
import canopen

from stubs.cia402_drive.bus_claim import BusClaim
from stubs.cia402_drive.dictionary import object_dictionary
from stubs.cia402_drive.drive import EmulatedDrive
from stubs.cia402_drive.encoders import Encoder, LinearEncoder
from stubs.cia402_drive.gripper import GripperLink
from stubs.cia402_drive.profile import (
    EMCY_OVER_CURRENT,
    ERROR_REGISTER_CURRENT,
    NMT_COB_ID,
    SYNC_COB_ID,
)
from stubs.cia402_drive.udp_bus import confine_to_host, fileno, widen_receive_buffer
from stubs.plant.base import KinematicPlant, Plant
from stubs.reading_glitch import ReadingGlitch

log = logging.getLogger(__name__)

MAX_SYNC_GAP_PERIODS = 4
"""A SYNC after a longer pause advances the plant by at most this many cycle periods."""
CLOCK_TICK_S = 0.001
"""The drives' own clock: how often heartbeat consumers are checked (the emulated drive's
check interval) and, while SYNC is late, the plant is stepped."""
LATE_SYNC_PERIODS = 1.5
"""SYNC is late this many cycle periods after the last one: the clock steps the plant."""
HEARTBEAT_COB_IDS = range(0x701, 0x780)
"""Heartbeats (and boot-ups) of node ids 1-127: a drive's consumer may watch any of them."""
DEFAULT_CYCLE_US = 2000
GRIPPER_COUNTS_PER_M = 1_000_000.0
"""The gripper drive's stroke sensor as built by default: one count per micrometre of opening
(a drive made to match the driver's default; tests check that the two agree)."""
MAX_PROFILE_VELOCITY_RAD_S = 2 * math.pi
"""0x607F of a joint drive as built by default: a motor faster than any joint limit the shipped
manifests set."""
GRIPPER_MAX_VELOCITY_M_S = 0.15


@dataclass(frozen=True, slots=True)
class EmulatorConfig:
    interface: str
    channel: str
    node_ids: tuple[int, ...]
    encoders: tuple[Encoder, ...]
    udp_port: int = 43113
    following_error_rad: float = 0.25
    plant_timestep_ns: int = 1_000_000
    q0: tuple[float, ...] | None = None
    """Initial joint positions; None: the plant's own default pose."""
    gripper_node: int | None = None
    """One more drive, whose position is the plant's gripper opening; None: no gripper drive."""
    gripper_counts_per_m: float = GRIPPER_COUNTS_PER_M
    max_profile_velocity: float = MAX_PROFILE_VELOCITY_RAD_S
    """Every joint drive's 0x607F, in rad/s (reported, not enforced)."""

    def __post_init__(self) -> None:
        if len(self.encoders) != len(self.node_ids):
            raise ValueError(f"{len(self.encoders)} encoders for {len(self.node_ids)} nodes")
        if self.gripper_node is not None and (
                self.gripper_node in self.node_ids or not 1 <= self.gripper_node <= 127):
            raise ValueError(f"gripper node {self.gripper_node} must be within 1..127 and not "
                             "one of the joint nodes")
        if not self.gripper_counts_per_m > 0:
            raise ValueError("gripper_counts_per_m must be positive")


@dataclass(slots=True)
class _SyncClock:
    last: float | None = None
    """When the plant was last stepped (monotonic)."""
    last_sync: float | None = None
    debt_ns: int = 0
    count: int = 0


class DriveEmulator:
    def __init__(self, config: EmulatorConfig, plant: Plant | None = None) -> None:
        self.config = config
        self.plant: Plant = plant or KinematicPlant(dof=len(config.node_ids),
                                                    timestep_ns=config.plant_timestep_ns)
        if self.plant.dof != len(config.node_ids):
            raise ValueError(f"the plant has {self.plant.dof} joints, --nodes lists "
                             f"{len(config.node_ids)} drives")
        if config.q0 is not None:
            self.plant.reset(config.q0)
        self.lock = threading.RLock()
        self.drives: dict[int, EmulatedDrive] = {}
        """Every drive by node id: the joints in joint order, then the gripper."""
        self._joints: tuple[EmulatedDrive, ...] = ()
        self.gripper: GripperLink | None = None
        self._network: canopen.Network | None = None
        self._claim: BusClaim | None = None
        self._clock = _SyncClock()
        self._stopping = threading.Event()
        self._fd = -1
        self._clock_thread = threading.Thread(target=self._keep_time, name="drive-clock",
                                              daemon=True)
        self.faults: dict[str, Callable[..., None]] = {
            "emcy": self._fault_emcy,
            "heartbeat_stop": self._fault_heartbeat_stop,
            "quick_stop": self._fault_quick_stop,
            "ignore_mode": self._fault_ignore_mode,
            "reading_glitch": self._fault_reading_glitch,
            "clear": self._fault_clear,
        }
        self.glitch = ReadingGlitch()
        """An injected reading glitch: one SYNC's (or a duration's) reported positions."""

    # -- lifetime ------------------------------------------------------------------------------

    def start(self) -> DriveEmulator:
        """Raises:
            BusInUse: another emulator runs drives on this ``udp_multicast`` bus.
        """
        if self.config.interface == "udp_multicast":
            self._claim = BusClaim(self.config.channel, self.config.udp_port)
        try:
            bus = can.Bus(interface=self.config.interface, channel=self.config.channel,
                          **self._bus_options())
        except BaseException:
            self._release_claim()
            raise
        try:
            widen_receive_buffer(bus)
            if self.config.interface == "udp_multicast":
                confine_to_host(bus, self.config.channel)
            network = canopen.Network(bus)
            network.NOTIFIER_CYCLE = 0.05  # bounds how long stop() waits for the reader thread
            self._add_drives(network)
            network.subscribe(SYNC_COB_ID, self._on_sync)
            network.subscribe(NMT_COB_ID, self._on_nmt)
            for cob_id in HEARTBEAT_COB_IDS:
                network.subscribe(cob_id, self._on_heartbeat)
            self._network = network.connect()
            self._fd = fileno(bus)
        except BaseException:
            bus.shutdown()
            self._release_claim()
            raise
        for drive in self.drives.values():
            drive.node.nmt.state = "RESET"  # sends the boot-up message
            drive.node.nmt.state = "PRE-OPERATIONAL"
        self._clock_thread.start()
        return self

    def _add_drives(self, network: canopen.Network) -> None:
        state = self.plant.state()
        for joint, (node_id, encoder) in enumerate(
            zip(self.config.node_ids, self.config.encoders, strict=True)
        ):
            self.drives[node_id] = EmulatedDrive(
                self._create_node(network, node_id), encoder, self.lock, state.q[joint],
                self.config.following_error_rad, self.config.max_profile_velocity)
        self._joints = tuple(self.drives.values())
        node_id = self.config.gripper_node
        if node_id is not None:
            # No following-error supervision: a grasp holds the fingers off their target.
            drive = EmulatedDrive(self._create_node(network, node_id),
                                  LinearEncoder(self.config.gripper_counts_per_m), self.lock,
                                  state.gripper, None, GRIPPER_MAX_VELOCITY_M_S)
            self.drives[node_id] = drive
            self.gripper = GripperLink(drive)

    def _create_node(self, network: canopen.Network, node_id: int) -> canopen.LocalNode:
        return network.create_node(node_id, object_dictionary(node_id))

    def stop(self) -> None:
        network, self._network = self._network, None
        if network is None:
            return
        self._stopping.set()
        if self._clock_thread.is_alive():
            self._clock_thread.join(timeout=1.0)
        for drive in self.drives.values():
            drive.node.nmt.stop_heartbeat()
        network.disconnect()
        self._release_claim()

    def _release_claim(self) -> None:
        claim, self._claim = self._claim, None
        if claim is not None:
            claim.release()

    def __enter__(self) -> DriveEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _bus_options(self) -> dict[str, Any]:
        if self.config.interface == "udp_multicast":
            return {"port": self.config.udp_port}
        return {}

    # -- frames --------------------------------------------------------------------------------

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        # Runs after each LocalNode's own NMT handler (subscribed earlier), so states are new.
        with self.lock:
            for drive in self.drives.values():
                drive.on_nmt()

    def _on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        now = time.monotonic()
        with self.lock:
            for drive in self.drives.values():
                drive.on_heartbeat(can_id - 0x700, now)

    def _keep_time(self) -> None:
        while not self._stopping.wait(CLOCK_TICK_S):
            with self.lock:
                now = time.monotonic()
                overdue = [d for d in self.drives.values() if d.consumer.overdue(now)]
                if overdue and not self._frames_waiting():
                    for drive in overdue:
                        drive.supervise(now)
                last_sync = self._clock.last_sync
                if last_sync is None or now - last_sync > LATE_SYNC_PERIODS * (
                        self._cycle_ns() * 1e-9):
                    self._move_plant()

    def _frames_waiting(self) -> bool:
        """Received frames not read yet (a bus without a file descriptor, ``virtual``, is
        read by a thread of this process that keeps up: never)."""
        if self._fd < 0:
            return False
        readable, _, _ = select.select([self._fd], [], [], 0)
        return bool(readable)

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            self._clock.last_sync = time.monotonic()
            operational = [d for d in self.drives.values() if d.operational]
            for drive in operational:
                drive.apply_pending_rpdos()
            self._move_plant()
            self._clock.count += 1
            for drive in operational:
                drive.transmit_tpdos(self._clock.count)

    def _move_plant(self) -> None:
        now = self.plant.state()
        self.plant.command_position([d.joint_target(q) for d, q in zip(self._joints, now.q,
                                                                        strict=True)])
        if self.gripper is not None:
            self.gripper.command(self.plant, now.gripper)
        steps = self._steps_due()
        if steps:
            self.plant.step(steps)
        state = self.plant.state()
        glitched = self.glitch.apply(state.q)
        for drive, q, qd, effort, reported in zip(self._joints, state.q, state.qd, state.effort,
                                                  glitched, strict=True):
            drive.update_actual(q, qd, effort, reported - q)
        if self.gripper is not None:
            self.gripper.measure(state)

    def _steps_due(self) -> int:
        """Plant steps for the wall time since the plant last stepped (at a SYNC or on the
        clock), capped at a few cycles."""
        now = time.monotonic()
        cycle_ns = self._cycle_ns()
        elapsed_ns = cycle_ns if self._clock.last is None else int(1e9 * (now - self._clock.last))
        self._clock.last = now
        self._clock.debt_ns += min(elapsed_ns, MAX_SYNC_GAP_PERIODS * cycle_ns)
        steps, self._clock.debt_ns = divmod(self._clock.debt_ns, self.plant.timestep_ns)
        return steps

    def _cycle_ns(self) -> int:
        first = self._joints[0]
        return (first.cycle_us or DEFAULT_CYCLE_US) * 1000

    # -- fault injection -----------------------------------------------------------------------

    def inject(self, fault: str, **fields: Any) -> None:
        """Switch a named fault on: emcy, heartbeat_stop, quick_stop, ignore_mode, clear."""
        if fault not in self.faults:
            raise KeyError(f"unknown fault {fault!r}; known: {', '.join(self.faults)}")
        with self.lock:
            self.faults[fault](**fields)

    def drive(self, node: int | None) -> EmulatedDrive:
        if node is None:
            return next(iter(self.drives.values()))
        if node not in self.drives:
            raise KeyError(f"no drive with node id {node}")
        return self.drives[node]

    def report(self) -> dict[str, Any]:
        """Every drive as it is now, by node id (the test control port's ``drives``)."""
        with self.lock:
            return {str(node_id): {
                "state": str(drive.state), "statusword": drive.statusword(),
                "nmt": drive.node.nmt.state, "abort_option": int(drive.abort_option),
                "consumer": {"producer": drive.consumer.producer,
                             "timeout_ms": round(drive.consumer.timeout_s * 1000)},
                "connection_losses": [str(loss) for loss in drive.connection_losses],
                "error_code": drive.error_code,
            } for node_id, drive in self.drives.items()}

    def motion(self) -> dict[str, Any]:
        """The motion commands each drive was given (the test control port's ``motion``)."""
        with self.lock:
            by_node = {str(i): drive.motion_commands for i, drive in self.drives.items()}
        return {"motion_commands": sum(by_node.values()), "by_node": by_node}

    def _fault_emcy(self, node: int | None = None, code: int = EMCY_OVER_CURRENT,
                    register: int = ERROR_REGISTER_CURRENT) -> None:
        self.drive(node).fault(int(code), int(register))

    def _fault_heartbeat_stop(self, node: int | None = None) -> None:
        self.drive(node).stop_heartbeat()

    def _fault_quick_stop(self, node: int | None = None) -> None:
        self.drive(node).machine.quick_stop_input()

    def _fault_ignore_mode(self, node: int | None = None) -> None:
        self.drive(node).mode_locked = True

    def _fault_reading_glitch(self, **request: Any) -> None:
        self.glitch.start(request)

    def _fault_clear(self) -> None:
        """Remove injected conditions; a latched FAULT stays until the master resets it."""
        self.glitch.clear()
        for drive in self.drives.values():
            drive.mode_locked = False
            drive.machine.quick_stop_input(active=False)
            if drive.heartbeat_stopped:
                drive.restart_heartbeat()


def encoders_for(node_ids: Sequence[int], counts_per_rev: int,
                 directions: Sequence[int] = (), offsets: Sequence[int] = ()) -> tuple[
                     Encoder, ...]:
    directions = directions or [1] * len(node_ids)
    offsets = offsets or [0] * len(node_ids)
    return tuple(Encoder(counts_per_rev, d, o) for d, o in zip(directions, offsets, strict=True))
