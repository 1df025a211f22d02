"""Blocking steps that bring drives up, one node at a time: only ever run on the device thread.

Each step either leaves the drive as described or raises a driver error naming the node and
what to check. Steps use SDO (answered by the drive whatever its PDO state) except the 402
state changes, which go through canopen's ``BaseNode402.state`` and need the bus cycle running.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

from canopen.sdo import SdoAbortedError, SdoCommunicationError

from drivers.base import ControlConfig, DriverInitError
from drivers.canopen402 import watchdog
from drivers.canopen402._sdk import Network, Node402, PdoMap, PdoMaps
from drivers.canopen402.drive_state import walk_to
from drivers.canopen402.health import HealthMonitor
from drivers.canopen402.settings import CiA402Settings
from drivers.canopen402.tables import (
    CSP_MODE_NAME,
    DEVICE_PROFILE_402,
    EMCY_NAMES,
    OBJECT_BYTES,
    QUICK_STOP_HOLD,
    RPDO_LAYOUT,
    TPDO_LAYOUT,
    Controlword,
    DriveState,
    Index,
    Mode,
    NmtState,
    decode_state,
)
from drivers.canopen402.units import JointScale

SYNCHRONOUS = 1
"""PDO transmission type: RPDO applied at, TPDO sent on, every SYNC."""

FAULT_RESET_TIMEOUT_S = 0.5


def bring_up(nodes: Sequence[Node402], settings: CiA402Settings,
             health: HealthMonitor) -> None:
    """At connect: NMT pre-operational, every node probed, heartbeats started, the watchdog's
    reaction set, no drive left in FAULT (or the connect refused)."""
    for node in nodes:
        node.nmt.state = "PRE-OPERATIONAL"  # SDO configuration is allowed from here on
    for node in nodes:
        probe(node, settings)
    start_heartbeats(nodes, settings, health)
    watchdog.prepare_all(nodes, settings)
    for node in nodes:
        clear_fault(node, settings, health)


def settle(nodes: Sequence[Node402], settings: CiA402Settings) -> None:
    """At the end of configure: CSP selected and confirmed, every drive SWITCH ON DISABLED."""
    for node in nodes:
        select_csp(node, settings)
        walk_to(node, DriveState.SWITCH_ON_DISABLED, settings)


def probe(node: Node402, settings: CiA402Settings) -> None:
    """Check the node answers SDO and is a CiA 402 drive."""
    who = settings.node_label(node.id)
    key = "gripper_node" if node.id == settings.gripper_node else "node_ids"
    try:
        device_type = node.sdo[Index.DEVICE_TYPE].raw
    except SdoCommunicationError as error:
        raise DriverInitError(
            settings.name, f"{who} does not answer on {settings.describe_bus()} (no SDO reply "
            f"within {settings.sdo_timeout_s} s): check {key}, that the drive is powered, the "
            "wiring and termination, and the bitrate",
        ) from error
    except SdoAbortedError as error:
        raise DriverInitError(settings.name, f"{who} refused to report its device type "
                              f"(0x1000): {error}") from error
    if device_type & 0xFFFF != DEVICE_PROFILE_402:
        raise DriverInitError(
            settings.name, f"{who} is not a CiA 402 drive: device type 0x{device_type:08X}"
            f" (profile {device_type & 0xFFFF}); check {key}",
        )


def start_heartbeats(nodes: Sequence[Node402], settings: CiA402Settings,
                     health: HealthMonitor) -> None:
    """Make every drive produce heartbeats, then wait for the first of each, all together.

    (canopen's ``wait_for_bootup`` is racy: a boot-up sent before the wait starts is missed.)
    """
    since = time.monotonic()
    for node in nodes:
        node.sdo[Index.HEARTBEAT_TIME].raw = settings.heartbeat_period_ms
    for node in nodes:
        if not health.wait_heartbeat(node.id, since, settings.boot_timeout_s):
            raise DriverInitError(
                settings.name, f"{settings.node_label(node.id)} answers SDO but sent no "
                f"heartbeat within {settings.boot_timeout_s} s of 0x1017 := "
                f"{settings.heartbeat_period_ms} ms",
            )


def clear_fault(node: Node402, settings: CiA402Settings, health: HealthMonitor) -> None:
    """Refuse a drive that is in FAULT, or reset it when the settings allow it."""
    if decode_state(node.sdo[Index.STATUSWORD].raw) not in (
        DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE
    ):
        health.clear_emcy(node.id)
        return
    detail = _fault_detail(node)
    if not settings.reset_faults_on_connect:
        raise DriverInitError(
            settings.name, f"{settings.node_label(node.id)} is in FAULT at start ({detail}); "
            "remove the cause, then reset it on the drive or set reset_faults_on_connect = true",
        )
    node.sdo[Index.CONTROLWORD].raw = Controlword.DISABLE_VOLTAGE
    node.sdo[Index.CONTROLWORD].raw = Controlword.FAULT_RESET  # the reset acts on the rising edge
    deadline = time.monotonic() + FAULT_RESET_TIMEOUT_S
    while decode_state(node.sdo[Index.STATUSWORD].raw) is DriveState.FAULT:
        if time.monotonic() > deadline:
            raise DriverInitError(settings.name, f"{settings.node_label(node.id)} stays in FAULT "
                                  f"after a fault reset ({detail}): the cause is still present")
        time.sleep(0.01)
    health.clear_emcy(node.id)


def _fault_detail(node: Node402) -> str:
    code = node.sdo[Index.ERROR_CODE].raw
    register = node.sdo[Index.ERROR_REGISTER].raw
    name = EMCY_NAMES.get(code, "see the drive manual")
    return f"error code 0x{code:04X} ({name}), error register 0x{register:02X}"


def write_parameters(node: Node402, scale: JointScale, control: ControlConfig,
                     joint: int) -> int:
    """Cycle time, interpolation period, quick-stop behaviour and position limits.

    Returns:
        The motor rated torque (0x6076, mN·m), the unit of the torque the drive reports.
    """
    write_cycle(node, control)
    write_limits(node, scale.to_counts(control.q_lower[joint]),
                 scale.to_counts(control.q_upper[joint]))
    return int(node.sdo[Index.RATED_TORQUE].raw)


def write_cycle(node: Node402, control: ControlConfig) -> None:
    """What every drive on the bus needs alike: cycle time, interpolation, quick-stop option."""
    period_us = control.period_ns // 1000
    node.sdo[Index.COMM_CYCLE_PERIOD].raw = period_us
    value, exponent = interpolation_period(period_us)
    node.sdo[Index.INTERPOLATION_PERIOD][1].raw = value
    node.sdo[Index.INTERPOLATION_PERIOD][2].raw = exponent
    node.sdo[Index.QUICK_STOP_OPTION].raw = QUICK_STOP_HOLD


def write_limits(node: Node402, a: int, b: int) -> None:
    """0x607D in counts, lower first whatever the sign convention of the axis."""
    low, high = sorted((a, b))
    node.sdo[Index.SOFTWARE_LIMITS][1].raw = low
    node.sdo[Index.SOFTWARE_LIMITS][2].raw = high


EMULATED_INTERFACES = frozenset({"virtual", "udp_multicast"})
"""Buses without a bitrate: their limit is CPU time, which the bus cycle's latency shows."""


def frame_bits(data_bytes: int) -> int:
    """Worst-case length of a CAN 2.0A data frame with bit stuffing (ISO 11898-1)."""
    return 47 + 8 * data_bytes + (34 + 8 * data_bytes - 1) // 4


def bus_load(drives: int, period_s: float, bitrate: int,
             heartbeat_interval_s: float | None = None) -> float:
    """Fraction of the bitrate the bus cycle of this layout takes, worst case.

    Per drive: the RPDO and every TPDO; per cycle: one SYNC; and warden's heartbeat (one data
    byte) every ``heartbeat_interval_s`` while the drives watch it.
    """
    sizes = [_layout_bytes(layout) for layout in (*RPDO_LAYOUT, *TPDO_LAYOUT)]
    bits = drives * sum(frame_bits(size) for size in sizes) + frame_bits(0)
    heartbeat = frame_bits(1) / heartbeat_interval_s if heartbeat_interval_s else 0.0
    return (bits / period_s + heartbeat) / bitrate


def _layout_bytes(indices: tuple[Index, ...]) -> int:
    return sum(OBJECT_BYTES[index] for index in indices)


def check_bus_load(settings: CiA402Settings, period_s: float) -> None:
    """Refuse a control rate a physical CAN bus cannot carry with this PDO layout."""
    if settings.interface in EMULATED_INTERFACES:
        return
    drives = len(settings.drive_ids)  # the gripper's PDOs share the bus with the joints'
    heartbeat = settings.heartbeat_interval_s(period_s) if settings.watchdog_ms else None
    load = bus_load(drives, period_s, settings.bitrate, heartbeat)
    if load > 1.0:
        raise DriverInitError(
            settings.name, f"{drives} drives at {1 / period_s:.0f} Hz need "
            f"{100 * load:.0f}% of {settings.bitrate} bit/s (worst case): lower the control "
            "rate or split the drives over more CAN buses",
        )


def interpolation_period(period_us: int) -> tuple[int, int]:
    """0x60C2 as (value, exponent): period = value * 10**exponent s, value an UNSIGNED8.

    The coarsest exact unit first: many drives accept only milliseconds here.
    """
    for exponent in (-3, -4, -5, -6):
        scale = 10 ** (exponent + 6)
        if period_us % scale == 0 and period_us // scale <= 0xFF:
            return period_us // scale, exponent
    return min(round(period_us / 1000), 0xFF), -3


def map_pdos(node: Node402) -> None:
    """RPDO1: controlword + target + mode; TPDO1: statusword + position + torque; TPDO2: velocity +
    mode display.

    Read the drive's current PDO set first, so that PDOs it had enabled and this layout does not
    use are saved back disabled, not left running.
    """
    node.rpdo.read()
    node.tpdo.read()
    _apply_layout(node.rpdo, RPDO_LAYOUT)
    _apply_layout(node.tpdo, TPDO_LAYOUT)
    node.pdo.save()
    node.setup_402_state_machine(read_pdos=False)


def stop_echo(network: Network, node: Node402) -> None:
    """Unsubscribe our own RPDOs: a bus that echoes frames (udp_multicast) would otherwise
    make canopen treat them as received and overwrite the setpoints we are sending."""
    for number in list(node.rpdo):
        pdo = node.rpdo[number]
        subscribed = network.subscribers.get(pdo.cob_id or -1, [])
        if pdo.enabled and pdo.on_message in subscribed:
            network.unsubscribe(pdo.cob_id or -1, pdo.on_message)


def _apply_layout(maps: PdoMaps, layout: tuple[tuple[Index, ...], ...]) -> None:
    for number in list(maps):
        pdo: PdoMap = maps[number]
        pdo.clear()
        pdo.enabled = number <= len(layout)
        if not pdo.enabled:
            continue
        pdo.cob_id = pdo.cob_id or pdo.predefined_cob_id
        pdo.trans_type = SYNCHRONOUS
        for index in layout[number - 1]:
            pdo.add_variable(index)


def enter_operational(nodes: Sequence[Node402], settings: CiA402Settings,
                      health: HealthMonitor) -> None:
    """NMT start, confirmed by each drive's own heartbeat (NMT commands are unacknowledged)."""
    since = time.monotonic()
    for node in nodes:
        node.nmt.state = "OPERATIONAL"
    timeout_s = settings.boot_timeout_s + 3 * settings.heartbeat_period_ms / 1000.0
    for node in nodes:
        if not health.wait_heartbeat(node.id, since, timeout_s, NmtState.OPERATIONAL):
            raise DriverInitError(settings.name, f"{settings.node_label(node.id)} did not report "
                                  f"OPERATIONAL within {timeout_s:.2f} s of the NMT start command")


def select_csp(node: Node402, settings: CiA402Settings) -> None:
    """Switch to cyclic synchronous position and wait for 0x6061 to confirm it ourselves.

    canopen's ``op_mode`` setter gives up after a fixed 0.5 s and then only logs a warning.
    """
    node.op_mode = CSP_MODE_NAME
    deadline = time.monotonic() + settings.state_timeout_s
    while (shown := node.sdo[Index.MODES_DISPLAY].raw) != Mode.CYCLIC_SYNCHRONOUS_POSITION:
        if time.monotonic() > deadline:
            raise DriverInitError(
                settings.name, f"{settings.node_label(node.id)} did not confirm {CSP_MODE_NAME} "
                f"mode within {settings.state_timeout_s} s: 0x6061 reads {shown} (0x6502 "
                f"supported modes 0x{node.sdo[Index.SUPPORTED_MODES].raw:08X})",
            )
        time.sleep(0.01)
