"""PDO plumbing of the emulated drive: TPDO layouts compiled for the SYNC path, and leaving the
network's subscriptions of a PDO the drive no longer uses."""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass

from canopen import Network
from canopen.objectdictionary import ODVariable
from canopen.pdo import PdoMap


@dataclass(frozen=True, slots=True)
class TpdoPacker:
    """One TPDO's layout, compiled once per NMT start: SYNC then only packs numbers.

    (Going through ``LocalNode.get_data`` and ``PdoVariable.set_data`` per object cost most of
    a SYNC's time with six drives.)
    """

    cob_id: int
    every: int
    size: int
    fields: tuple[tuple[ODVariable, struct.Struct, int], ...]
    """(object, encoding, byte offset) per mapped object."""

    @classmethod
    def from_map(cls, pdo: PdoMap) -> TpdoPacker:
        fields = []
        for var in pdo:
            if not var.length:
                continue
            if var.offset % 8 or var.length % 8:
                raise ValueError(f"TPDO 0x{pdo.cob_id:X}: only byte-aligned objects are emulated")
            fields.append((var.od, var.od.STRUCT_TYPES[var.od.data_type], var.offset // 8))
        size = sum(f[1].size for f in fields)
        return cls(int(pdo.cob_id or 0), max(1, int(pdo.trans_type or 1)), size, tuple(fields))

    def pack(self, value: Callable[[ODVariable], int]) -> bytearray:
        data = bytearray(self.size)
        for od, encoding, offset in self.fields:
            encoding.pack_into(data, offset, value(od))
        return data


def unsubscribe(network: Network, pdo: PdoMap) -> None:
    if pdo.cob_id is not None and pdo.on_message in network.subscribers.get(pdo.cob_id, []):
        network.unsubscribe(pdo.cob_id, pdo.on_message)
