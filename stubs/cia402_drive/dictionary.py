"""The emulated drive's object dictionary, built in code from CiA 301 and CiA 402.

A real drive's dictionary lives in its firmware and its EDS file only describes it; the two are
written separately and can disagree. So it is here: this module builds what the drive serves,
and the driver reads its own EDS (``drivers/canopen402/cia402_drive.eds``);
tests/drivers/test_cia402_dictionary.py checks that the EDS describes this dictionary.

Defaults are the drive's state at power-on: the predefined connection set (RPDO1 = controlword
+ target position, TPDO1 = statusword + position actual, TPDO2 = velocity actual; the other
PDOs present but invalid), no SYNC period and no heartbeat configured (neither produced nor
consumed), a lost connection faults the drive (0x6007 = 1), CSP the only mode.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from canopen import ObjectDictionary
from canopen.objectdictionary import ODArray, ODRecord, ODVariable, datatypes

from stubs.cia402_drive.profile import (
    DEVICE_TYPE_SERVO,
    NO_FOLLOWING_LIMIT,
    PDO_CHANNELS,
    SUPPORTED_MODE_BITS,
    SYNC_COB_ID,
    AbortConnection,
    Index,
    Mode,
)

U8, U16, U32 = datatypes.UNSIGNED8, datatypes.UNSIGNED16, datatypes.UNSIGNED32
I8, I16, I32 = datatypes.INTEGER8, datatypes.INTEGER16, datatypes.INTEGER32
PDO_INVALID = 1 << 31
"""COB-ID bit 31: the PDO exists but is not valid (CiA 301, 7.5.2.35)."""
MAPPING_ENTRIES = 8
RPDO_COB_BASE = (0x200, 0x300, 0x400, 0x500)
TPDO_COB_BASE = (0x180, 0x280, 0x380, 0x480)
VALID_RPDOS = 1
VALID_TPDOS = 2
TRANSMISSION_EVENT = 255
"""Transmission type 255: event-driven (device profile specific)."""
RATED_TORQUE_MNM = 1000
RPDO_DEFAULT_MAPS: tuple[tuple[tuple[Index, int], ...], ...] = (
    ((Index.CONTROLWORD, 16), (Index.TARGET_POSITION, 32)),  # RPDO1
)
TPDO_DEFAULT_MAPS: tuple[tuple[tuple[Index, int], ...], ...] = (
    ((Index.STATUSWORD, 16), (Index.POSITION_ACTUAL, 32)),  # TPDO1
    ((Index.VELOCITY_ACTUAL, 32),),  # TPDO2
)
"""(object, bit length) mapped by default; the channels not listed map nothing."""
IDENTITY = (("Vendor-ID", 0), ("Product code", 0x402), ("Revision number", 0x0001_0000),
            ("Serial number", 1))


@dataclass(frozen=True, slots=True)
class Entry:
    """One variable: what the EDS would say about it."""

    name: str
    data_type: int
    access: str
    default: int = 0
    pdo_mappable: bool = False
    relative: bool = False
    """The default is a COB-ID that already includes the node id (canopen's ``relative``)."""


PROFILE: dict[Index, Entry] = {
    Index.ABORT_CONNECTION_OPTION: Entry("Abort connection option code", I16, "rw",
                                         AbortConnection.FAULT_SIGNAL),
    Index.ERROR_CODE: Entry("Error code", U16, "ro", pdo_mappable=True),
    Index.CONTROLWORD: Entry("Controlword", U16, "rw", pdo_mappable=True),
    Index.STATUSWORD: Entry("Statusword", U16, "ro", pdo_mappable=True),
    Index.QUICK_STOP_OPTION: Entry("Quick stop option code", I16, "rw", 2),
    Index.MODES_OF_OPERATION: Entry("Modes of operation", I8, "rw", Mode.NO_MODE, True),
    Index.MODES_DISPLAY: Entry("Modes of operation display", I8, "ro", Mode.NO_MODE, True),
    Index.POSITION_ACTUAL: Entry("Position actual value", I32, "ro", pdo_mappable=True),
    Index.FOLLOWING_ERROR_WINDOW: Entry("Following error window", U32, "rw", NO_FOLLOWING_LIMIT),
    Index.VELOCITY_ACTUAL: Entry("Velocity actual value", I32, "ro", pdo_mappable=True),
    Index.RATED_TORQUE: Entry("Motor rated torque", U32, "rw", RATED_TORQUE_MNM),
    Index.TORQUE_ACTUAL: Entry("Torque actual value", I16, "ro", pdo_mappable=True),
    Index.TARGET_POSITION: Entry("Target position", I32, "rw", pdo_mappable=True),
    Index.MAX_PROFILE_VELOCITY: Entry("Max profile velocity", U32, "rw"),
    Index.SUPPORTED_MODES: Entry("Supported drive modes", U32, "ro",
                                 sum(SUPPORTED_MODE_BITS.values())),
}
"""The CiA 402 single-variable objects the drive implements (0x607D, 0x608F, 0x6091 and 0x60C2
have sub-indices and are built in ``_profile``)."""
ENCODER_INCREMENTS = 2**23
"""0x608F's default: a 23-bit encoder on the motor shaft, one increment per position unit (the
drive sets its own build's resolution at power-on)."""


def object_dictionary(node_id: int) -> ObjectDictionary:
    """The dictionary of the drive with ``node_id``, its COB-IDs already resolved."""
    od = ObjectDictionary()
    for entry in (*_communication(node_id), *_profile()):
        od.add_object(entry)
    return od


def _communication(node_id: int) -> Iterator[ODVariable | ODRecord | ODArray]:
    yield _variable(Index.DEVICE_TYPE, Entry("Device type", U32, "ro", DEVICE_TYPE_SERVO))
    yield _variable(Index.ERROR_REGISTER, Entry("Error register", U8, "ro", 0, True))
    yield _variable(Index.COB_ID_SYNC, Entry("COB-ID SYNC", U32, "rw", SYNC_COB_ID))
    yield _variable(Index.COMM_CYCLE_PERIOD, Entry("Communication cycle period", U32, "rw"))
    consumers = ODArray("Consumer heartbeat time", Index.HEARTBEAT_CONSUMER)
    _add_members(consumers, [Entry("Consumer heartbeat time", U32, "rw")])  # one producer
    yield consumers
    yield _variable(Index.HEARTBEAT_TIME, Entry("Producer heartbeat time", U16, "rw"))
    yield _record(Index.IDENTITY, "Identity object",
                  [Entry(name, U32, "ro", value) for name, value in IDENTITY])
    for n in range(PDO_CHANNELS):
        yield _rpdo_communication(n, node_id)
    for n in range(PDO_CHANNELS):
        yield _mapping(Index.RPDO_MAPPING + n, f"RPDO{n + 1} mapping parameter",
                       RPDO_DEFAULT_MAPS[n] if n < len(RPDO_DEFAULT_MAPS) else ())
    for n in range(PDO_CHANNELS):
        yield _tpdo_communication(n, node_id)
    for n in range(PDO_CHANNELS):
        yield _mapping(Index.TPDO_MAPPING + n, f"TPDO{n + 1} mapping parameter",
                       TPDO_DEFAULT_MAPS[n] if n < len(TPDO_DEFAULT_MAPS) else ())


def _profile() -> Iterator[ODVariable | ODRecord | ODArray]:
    for index, entry in PROFILE.items():
        yield _variable(index, entry)
    limits = ODArray("Software position limit", Index.SOFTWARE_LIMITS)
    _add_members(limits, [Entry("Min position limit", I32, "rw"),
                          Entry("Max position limit", I32, "rw")])
    yield limits
    resolution = ODArray("Position encoder resolution", Index.POSITION_ENCODER_RESOLUTION)
    _add_members(resolution, [Entry("Encoder increments", U32, "rw", ENCODER_INCREMENTS),
                              Entry("Motor revolutions", U32, "rw", 1)])
    yield resolution
    gear = ODArray("Gear ratio", Index.GEAR_RATIO)
    _add_members(gear, [Entry("Motor revolutions", U32, "rw", 1),
                        Entry("Shaft revolutions", U32, "rw", 1)])
    yield gear
    yield _record(Index.INTERPOLATION_PERIOD, "Interpolation time period",
                  [Entry("Interpolation time period value", U8, "rw", 2),
                   Entry("Interpolation time index", I8, "rw", -3)])  # 2 × 10⁻³ s


def _rpdo_communication(n: int, node_id: int) -> ODRecord:
    cob_id = RPDO_COB_BASE[n] + node_id | (0 if n < VALID_RPDOS else PDO_INVALID)
    return _record(Index.RPDO_COMMUNICATION + n, f"RPDO{n + 1} communication parameter",
                   [Entry("COB-ID used by RPDO", U32, "rw", cob_id, relative=True),
                             Entry("Transmission type", U8, "rw", TRANSMISSION_EVENT)])


def _tpdo_communication(n: int, node_id: int) -> ODRecord:
    cob_id = TPDO_COB_BASE[n] + node_id | (0 if n < VALID_TPDOS else PDO_INVALID)
    return _record(Index.TPDO_COMMUNICATION + n, f"TPDO{n + 1} communication parameter",
                   [Entry("COB-ID used by TPDO", U32, "rw", cob_id, relative=True),
                             Entry("Transmission type", U8, "rw", TRANSMISSION_EVENT),
                             Entry("Inhibit time", U16, "rw"),
                             Entry("Compatibility entry", U8, "rw"),
                             Entry("Event timer", U16, "rw")])


def _mapping(index: int, name: str, mapped: tuple[tuple[Index, int], ...]) -> ODRecord:
    """A PDO mapping record: sub-index 0 counts the mapped objects (writable, as the master
    rewrites the mapping), then eight slots of (index << 16 | sub-index << 8 | bit length)."""
    words = [obj << 16 | bits for obj, bits in mapped]
    words += [0] * (MAPPING_ENTRIES - len(words))
    record = ODRecord(name, index)
    record.add_member(_member(index, 0, Entry("Number of mapped objects", U8, "rw",
                                              len(mapped))))
    for sub, word in enumerate(words, start=1):
        record.add_member(_member(index, sub, Entry(f"Mapped object {sub}", U32, "rw", word)))
    return record


def _record(index: int, name: str, members: list[Entry]) -> ODRecord:
    record = ODRecord(name, index)
    _add_members(record, members)
    return record


def _add_members(container: ODRecord | ODArray, members: list[Entry]) -> None:
    """Sub-index 0 ("highest sub-index supported", constant), then ``members`` from 1 on."""
    container.add_member(_member(container.index, 0, Entry(
        "Highest sub-index supported", U8, "const", len(members))))
    for sub, entry in enumerate(members, start=1):
        container.add_member(_member(container.index, sub, entry))


def _variable(index: int, entry: Entry) -> ODVariable:
    return _member(index, 0, entry)


def _member(index: int, subindex: int, entry: Entry) -> ODVariable:
    variable = ODVariable(entry.name, index, subindex)
    variable.data_type = entry.data_type
    variable.access_type = entry.access
    variable.default = entry.default
    variable.pdo_mappable = entry.pdo_mappable
    variable.relative = entry.relative
    return variable
