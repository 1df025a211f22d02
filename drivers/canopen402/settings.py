"""Settings of the CiA 402 driver: one manifest table, checked when it is read."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated, Any

from msgspec import Meta

from drivers.canopen402.udp_bus import check_group
from drivers.canopen402.units import (
    GRIPPER_COUNTS_PER_M,
    GRIPPER_STROKE_M,
    INT32_MAX,
    INT32_MIN,
    GripperScale,
    JointScale,
)
from drivers.settings import Settings, read_table

COUNTS_PER_REV_RANGE = (1, 2**31)
GEAR_RATIO_RANGE = (0.001, 10_000.0)
"""Motor turns per joint turn: strain-wave and cycloidal gears reach a few hundred."""
BITRATE_RANGE = (10_000, 1_000_000)
"""Classic CAN (CiA 301's bit rates run from 10 kbit/s to 1 Mbit/s)."""
NodeId = Annotated[int, Meta(ge=1, le=127)]
"""A CANopen node id."""
Unsigned16 = Annotated[int, Meta(ge=1, le=0xFFFF)]
"""A time in ms a drive keeps in an UNSIGNED16 object (0x1016, 0x1017)."""
TimeoutMs = Annotated[int, Meta(gt=0, le=60_000)]
TimeoutS = Annotated[float, Meta(gt=0.0, le=60.0)]
"""Every timeout is finite and at most a minute: a drive silent longer is not coming back."""


class CiA402Settings(Settings, frozen=True):
    """One CAN bus with one CiA 402 drive per joint, in joint order.

    ``interface``/``channel`` are python-can's (``socketcan``/``can0`` on a robot PC,
    ``virtual`` in-process, ``udp_multicast`` with a multicast group across processes).
    ``counts_per_rev`` has no default on purpose: a guessed scale moves the wrong distance.
    Empty ``direction``/``offset_counts``/``gear_ratio`` mean +1, 0 and 1.0 for every joint.
    ``gripper_node``, when set, is one more CiA 402 drive on the same bus whose position is the
    gripper opening (see :mod:`drivers.canopen402.gripper`).
    """

    interface: str
    channel: str
    node_ids: tuple[NodeId, ...]
    counts_per_rev: tuple[Annotated[float, Meta(ge=COUNTS_PER_REV_RANGE[0],
                                                le=COUNTS_PER_REV_RANGE[1])], ...]
    """A whole number of counts per motor turn; at most 2**31: a joint turn must fit the
    drive's INTEGER32 position."""
    direction: tuple[int, ...] = ()
    offset_counts: tuple[Annotated[int, Meta(ge=INT32_MIN, le=INT32_MAX)], ...] = ()
    gear_ratio: tuple[Annotated[float, Meta(ge=GEAR_RATIO_RANGE[0],
                                            le=GEAR_RATIO_RANGE[1])], ...] = ()
    name: str = "canopen402"
    udp_port: Annotated[int, Meta(ge=1, le=0xFFFF)] = 43113
    """Only for ``udp_multicast``: the bus is the group (``channel``) and this port; buses on one
    port with different groups are kept apart (``udp_bus.confine_to_host``)."""
    bitrate: Annotated[int, Meta(ge=BITRATE_RANGE[0], le=BITRATE_RANGE[1])] = 1_000_000
    eds_path: str = ""
    """The drives' EDS; empty: the generic CSP drive EDS shipped with this driver."""
    heartbeat_period_ms: Unsigned16 = 50
    """Written to each drive's 0x1017 (producer heartbeat time)."""
    heartbeat_timeout_ms: TimeoutMs = 250
    """Consumer side: a drive silent this long is LINK_LOST."""
    master_node_id: NodeId = 127
    """warden's own node id on the bus: its heartbeat is COB-ID 0x700 + this. Not a drive's."""
    master_heartbeat_ms: Unsigned16 = 10
    """warden's heartbeat producer time: while the drives watch it, the control loop's writes
    send it, at most this often (every ⌈time / period⌉ periods)."""
    watchdog_ms: Annotated[int, Meta(ge=0, le=0xFFFF)] = 300
    """Each drive's consumer time for warden's heartbeat (0x1016): a drive that misses it this
    long reacts as 0x6007 says (the joints quick-stop and hold, the gripper keeps its grip).
    Armed right before the loop's first tick, removed on deactivate; 0 switches it off.
    300, not 100: on the shared test machine the control loop stalls 105-245 ms a few times a
    run, and a CSP drive holds the last setpoint meanwhile. See docs/operations.md,
    "Device-side watchdogs"."""
    tpdo_timeout_ms: TimeoutMs = 200
    """No TPDO from a drive for this long while the bus cycle runs: WATCHDOG."""
    sdo_timeout_s: TimeoutS = 0.3
    boot_timeout_s: TimeoutS = 2.0
    """How long connect waits for a drive's first heartbeat after enabling it."""
    state_timeout_s: TimeoutS = 1.0
    """How long a drive may take to follow a 402 state change or a mode switch."""
    call_timeout_s: TimeoutS = 10.0
    """Deadline of each blocking step (bring-up, state changes) on the device thread."""
    reset_faults_on_connect: bool = False
    """Clear a drive's latched FAULT at connect; otherwise connect refuses a faulted drive."""
    gripper_node: NodeId | None = None
    """Node id of the gripper drive; None: this arm has no gripper on the bus."""
    gripper_counts_per_m: Annotated[float, Meta(gt=0.0)] = GRIPPER_COUNTS_PER_M
    """Gripper position counts per metre of opening. The default, one count per micrometre, is
    far finer than grasping needs (the cell's 20 mm peg has 0.75 mm of clearance per side in its
    hole) and the whole 0.085 m stroke is 85 000 counts, far inside INTEGER32; it is also the
    emulator's default. A real gripper drive: set its own scale here."""

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_node_ids(self.node_ids)
        self._check_gripper()
        joints = len(self.node_ids)
        for key in ("counts_per_rev", "direction", "offset_counts", "gear_ratio"):
            values = getattr(self, key)
            required = key == "counts_per_rev"
            if len(values) != joints and (required or values):
                raise ValueError(f"{key} has {len(values)} values for {joints} node ids")
        self._check_scales()
        if any(d not in (-1, 1) for d in self.direction):
            raise ValueError("direction values must be 1 or -1")
        if not self.heartbeat_period_ms < self.heartbeat_timeout_ms:
            raise ValueError("need 0 < heartbeat_period_ms < heartbeat_timeout_ms")
        self._check_watchdog()
        if self.interface == "udp_multicast" and (problem := check_group(self.channel)):
            raise ValueError(f"channel: {problem}")

    def _check_scales(self) -> None:
        for i, counts in enumerate(self.counts_per_rev):
            if counts != int(counts):
                raise ValueError(f"counts_per_rev[{i}] must be a whole number of counts, got "
                                 f"{counts}")

    def _check_watchdog(self) -> None:
        if self.master_node_id in self.drive_ids:
            raise ValueError(f"master_node_id must not be a drive's node id, got "
                             f"{self.master_node_id}")

    def heartbeat_interval_s(self, period_s: float) -> float:
        """How far apart warden's heartbeats go out at this control period: the first write at
        least ``master_heartbeat_ms`` after the previous one sends the next."""
        periods = math.ceil(self.master_heartbeat_ms / 1000.0 / period_s - 1e-9)
        return max(periods, 1) * period_s

    def check_watchdog(self, period_s: float) -> None:
        """At configure, once the control period is known.

        Raises:
            ValueError: ``watchdog_ms`` shorter than two heartbeat intervals, so that one
                heartbeat lost on the bus would already stop the arm.
        """
        interval_s = self.heartbeat_interval_s(period_s)
        if self.watchdog_ms and self.watchdog_ms / 1000.0 < 2 * interval_s:
            raise ValueError(
                f"watchdog_ms: {self.watchdog_ms} ms is shorter than two of warden's heartbeats "
                f"({1000 * interval_s:g} ms apart at master_heartbeat_ms = "
                f"{self.master_heartbeat_ms} and a {1000 * period_s:g} ms period): one lost "
                "heartbeat would stop the arm; raise it or lower master_heartbeat_ms")

    def _check_gripper(self) -> None:
        if self.gripper_node is not None and self.gripper_node in self.node_ids:
            raise ValueError(f"gripper_node {self.gripper_node} is also in node_ids: the "
                             "gripper needs a drive of its own")
        if GRIPPER_STROKE_M * self.gripper_counts_per_m > INT32_MAX:
            raise ValueError(f"gripper_counts_per_m = {self.gripper_counts_per_m} puts the "
                             f"{GRIPPER_STROKE_M} m stroke outside the drive's INTEGER32 "
                             "position range")

    @property
    def drive_ids(self) -> tuple[int, ...]:
        """Every drive on the bus: the joints in joint order, then the gripper if there is one."""
        gripper = () if self.gripper_node is None else (self.gripper_node,)
        return (*self.node_ids, *gripper)

    def node_label(self, node_id: int) -> str:
        """How errors name a drive: the gripper says so, since its id alone means little."""
        return f"node {node_id} (gripper)" if node_id == self.gripper_node else f"node {node_id}"

    def gripper_scale(self) -> GripperScale:
        return GripperScale(self.gripper_counts_per_m)

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any], where: str = "canopen402") -> CiA402Settings:
        return read_table(cls, table, where)

    def joint_scales(self) -> tuple[JointScale, ...]:
        joints = len(self.node_ids)
        direction = self.direction or (1,) * joints
        offsets = self.offset_counts or (0,) * joints
        gears = self.gear_ratio or (1.0,) * joints
        return tuple(
            JointScale(cpr, d, off, gear)
            for cpr, d, off, gear in zip(self.counts_per_rev, direction, offsets, gears,
                                         strict=True)
        )

    def bus_options(self) -> dict[str, Any]:
        """Keyword arguments for ``can.Bus`` beyond interface and channel."""
        options: dict[str, Any] = {"bitrate": self.bitrate}
        if self.interface == "udp_multicast":
            options["port"] = self.udp_port
        return options

    def describe_bus(self) -> str:
        port = f" port {self.udp_port}" if self.interface == "udp_multicast" else ""
        return f"interface {self.interface!r} channel {self.channel!r}{port}"


def _check_node_ids(node_ids: tuple[int, ...]) -> None:
    if not node_ids:
        raise ValueError("node_ids is empty")
    if len(set(node_ids)) != len(node_ids):
        raise ValueError("node ids must be unique")


def device_identity(settings: CiA402Settings) -> str | None:
    """The CAN bus ``settings`` address: interface and channel (and, on ``udp_multicast``, the
    port); None for python-can's ``virtual`` bus, which no other process can reach."""
    if settings.interface == "virtual":
        return None
    where = f" port {settings.udp_port}" if settings.interface == "udp_multicast" else ""
    return f"CAN bus {settings.interface} {settings.channel}{where}"


def device_watchdog(settings: CiA402Settings) -> str | None:
    """What stops the arm when warden's commands stop, as ``settings`` configure it; None: off."""
    if settings.watchdog_ms <= 0:
        return None
    return (f"every drive's heartbeat consumer: no heartbeat from warden for "
            f"{settings.watchdog_ms} ms and the joints quick-stop (0x6007)")


def device_watchdog_ms(settings: CiA402Settings, control_period_ms: float) -> float | None:
    """How long after warden's last heartbeat :func:`device_watchdog` stops the joints, in ms;
    None: off."""
    if settings.watchdog_ms <= 0:
        return None
    return float(settings.watchdog_ms)


ADDRESS_KEYS: Mapping[str, str] = {"interface": "udp_multicast", "channel": "239.0.0.1"}
"""The settings that say where the device is, with placeholders (``Driver.address_keys``)."""
