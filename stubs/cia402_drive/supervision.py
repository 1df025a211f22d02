"""How a drive notices that its master is gone (CiA 301 heartbeat consumer, NMT commands) and
what it then does (CiA 402-2, 0x6007 abort connection option code): pure logic, no bus.

The heartbeat consumer (0x1016) watches one producer: its node id and the time its heartbeat may
stay away. Monitoring starts with the first heartbeat received after the entry was written (CiA
301: an entry is not monitored before its producer was heard once); a heartbeat event ends it
until the producer is heard again, so one silence is one event.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from stubs.cia402_drive.profile import AbortConnection, DeviceCommand

CONSUMER_RESERVED_BITS = 0xFF00_0000
"""0x1016 bits 24-31 are reserved (CiA 301): a value with any of them set is refused."""


class ConnectionLoss(StrEnum):
    """The events CiA 402-2 names for 0x6007 that this emulator produces (bus-off and life
    guarding are not emulated: udp_multicast has no error frames, and no master guards)."""

    HEARTBEAT = "heartbeat"
    """The consumer's producer stayed silent longer than its consumer time."""
    NMT_STOPPED = "NMT stopped"
    NMT_RESET = "NMT reset"
    """Reset application or reset communication."""


REACTIONS: dict[AbortConnection, DeviceCommand | None] = {
    AbortConnection.NO_ACTION: None,
    AbortConnection.FAULT_SIGNAL: None,  # not a command: the drive faults (EmulatedDrive)
    AbortConnection.DISABLE_VOLTAGE: DeviceCommand.DISABLE_VOLTAGE,
    AbortConnection.QUICK_STOP: DeviceCommand.QUICK_STOP,
}
"""The device-control command each 0x6007 value applies as if it came from the master."""


@dataclass(slots=True)
class HeartbeatConsumer:
    """0x1016 sub-index 1 as the drive keeps it."""

    producer: int = 0
    timeout_s: float = 0.0
    last_heard: float | None = None
    """When the producer was last heard (monotonic); None: not monitoring."""

    @property
    def watching(self) -> bool:
        return 1 <= self.producer <= 127 and self.timeout_s > 0

    def configure(self, entry: int) -> None:
        """A new 0x1016 entry: monitoring waits for the producer's next heartbeat.

        Raises:
            ValueError: reserved bits set (the drive answers with an SDO abort).
        """
        if entry & CONSUMER_RESERVED_BITS:
            raise ValueError(f"0x1016 entry 0x{entry:08X} sets reserved bits 24-31")
        self.producer = (entry >> 16) & 0xFF
        self.timeout_s = (entry & 0xFFFF) / 1000.0
        self.last_heard = None

    def heard(self, producer: int, now: float) -> None:
        if self.watching and producer == self.producer:
            self.last_heard = now

    def overdue(self, now: float) -> bool:
        """The producer has been silent longer than the consumer time (and was heard before)."""
        return (self.watching and self.last_heard is not None
                and now - self.last_heard > self.timeout_s)

    def expire(self) -> None:
        """The heartbeat event happened: monitoring waits for the producer's next heartbeat,
        so that one silence is one event."""
        self.last_heard = None
