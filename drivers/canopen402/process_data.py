"""The drives' process data as the driver uses it: the bus cycle over their PDOs, and their
TPDO values as joint readings in SI units."""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence

from drivers.canopen402._sdk import Node402
from drivers.canopen402.cycle import BusCycle
from drivers.canopen402.link import Link
from drivers.canopen402.tables import Index
from drivers.canopen402.units import JointScale


def start_bus_cycle(link: Link, period_s: float, on_tpdo: Callable[[int], None]) -> BusCycle:
    """RPDOs + SYNC every ``period_s`` to every drive (the gripper's too); each enabled TPDO
    that arrives is told to the cycle (its round trip) and to ``on_tpdo`` (the drive is alive).
    """
    nodes = link.nodes
    tpdos = [(node.id, node.tpdo[n]) for node in nodes for n in list(node.tpdo)]
    tpdos = [(node_id, pdo) for node_id, pdo in tpdos if pdo.enabled and pdo.cob_id]
    cycle = BusCycle(link.network, [node.rpdo[1] for node in nodes],
                     [(node_id, int(pdo.cob_id or 0)) for node_id, pdo in tpdos], period_s)
    for node_id, pdo in tpdos:
        pdo.add_callback(functools.partial(_tpdo_seen, cycle, on_tpdo, node_id,
                                           int(pdo.cob_id or 0)))
    cycle.start()
    return cycle


def _tpdo_seen(cycle: BusCycle, on_tpdo: Callable[[int], None], node_id: int, cob_id: int,
               _pdo: object) -> None:
    on_tpdo(node_id)
    cycle.on_tpdo(node_id, cob_id)


def joint_readings(joints: Sequence[Node402], scales: Sequence[JointScale],
                   rated_torque: Sequence[int]) -> tuple[tuple[float, ...], ...]:
    """(q, qd, effort) in rad, rad/s and N·m from each joint's latest TPDO values."""
    q, qd, effort = [], [], []
    for node, scale, rated in zip(joints, scales, rated_torque, strict=True):
        values = node.tpdo_values
        q.append(scale.to_rad(values[Index.POSITION_ACTUAL]))
        qd.append(scale.velocity_to_rad(values[Index.VELOCITY_ACTUAL]))
        effort.append(scale.torque_to_nm(values[Index.TORQUE_ACTUAL], rated))
    return tuple(q), tuple(qd), tuple(effort)
