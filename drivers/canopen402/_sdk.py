"""The parts of canopen 2.4.1 and python-can 4.6.1 this driver uses, as typing Protocols.

canopen ships no useful type information for these objects; the Protocols say what the driver
relies on, so an upgrade that changes one of them fails in one obvious place. Objects are made
only by :func:`drivers.canopen402.link.open_link`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any, Protocol


class CanBus(Protocol):
    """python-can ``BusABC``."""

    def fileno(self) -> int: ...

    def recv(self, timeout: float | None = None) -> Any:
        """The next received ``can.Message``, or None once ``timeout`` passes."""
        ...

    def shutdown(self) -> None: ...


class Notifier(Protocol):
    """python-can ``Notifier``: dispatches received frames to canopen's listener."""

    listeners: list[Callable[[Any], Any]]

    def stop(self, timeout: float = 5.0) -> None: ...


class PdoVariable(Protocol):
    index: int
    subindex: int
    raw: Any


class PdoMap(Protocol):
    """One PDO (canopen ``PdoMap``); configured locally, then saved to the drive over SDO."""

    cob_id: int | None
    predefined_cob_id: int | None
    enabled: bool
    trans_type: int | None
    data: bytearray

    def __iter__(self) -> Iterator[PdoVariable]: ...

    def __getitem__(self, key: int | str) -> PdoVariable: ...

    def clear(self) -> None: ...

    def add_variable(self, index: int, subindex: int = 0) -> PdoVariable | None: ...

    def add_callback(self, callback: Callable[[PdoMap], None]) -> None: ...

    def on_message(self, can_id: int, data: bytearray, timestamp: float) -> None: ...

    def transmit(self) -> None: ...


class PdoMaps(Protocol):
    """``node.rpdo`` / ``node.tpdo``: maps numbered from 1."""

    def __getitem__(self, number: int) -> PdoMap: ...

    def __iter__(self) -> Iterator[int]: ...

    def read(self, from_od: bool = False) -> None:
        """Upload every map's configuration from the drive (SDO)."""
        ...


class PdoSet(Protocol):
    """``node.pdo``: both directions together."""

    def save(self) -> None: ...


class SdoVariable(Protocol):
    raw: Any

    def __getitem__(self, subindex: int) -> SdoVariable: ...


class SdoClient(Protocol):
    RESPONSE_TIMEOUT: float

    def __getitem__(self, index: int) -> SdoVariable: ...


class NmtMaster(Protocol):
    state: str

    def add_heartbeat_callback(self, callback: Callable[[int], None]) -> None: ...


class EmcyEntry(Protocol):
    """canopen ``EmcyError``: one EMCY frame."""

    code: int
    register: int

    def get_desc(self) -> str: ...


class EmcyConsumer(Protocol):
    def add_callback(self, callback: Callable[[EmcyEntry], None]) -> None: ...


class Node402(Protocol):
    """canopen ``BaseNode402``: a remote CiA 402 drive."""

    id: int
    sdo: SdoClient
    nmt: NmtMaster
    emcy: EmcyConsumer
    rpdo: PdoMaps
    tpdo: PdoMaps
    pdo: PdoSet
    tpdo_values: dict[int, int]
    op_mode: str
    controlword: int
    """Write-only: sets the controlword in the RPDO that the next bus cycle sends."""
    statusword: int
    """The last statusword a TPDO brought."""

    def check_statusword(self, timeout: float | None = None) -> int:
        """Wait for the next TPDO carrying the statusword (RuntimeError if none comes)."""
        ...

    def setup_402_state_machine(self, read_pdos: bool = True) -> None: ...


class SyncProducer(Protocol):
    def transmit(self, count: int | None = None) -> None: ...


class Network(Protocol):
    """canopen ``Network`` on an already-open bus."""

    bus: CanBus | None
    notifier: Notifier | None
    listeners: list[Any]
    sync: SyncProducer
    subscribers: dict[int, list[Callable[..., None]]]

    def add_node(self, node: Node402) -> Node402: ...

    def unsubscribe(self, can_id: int, callback: Callable[..., None] | None = None) -> None: ...
