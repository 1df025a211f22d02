"""dynamixel_sdk's PortHandler with three behaviours changed that matter on a shared machine.

- Packet timeouts: the SDK adds a hard-coded 34 ms (a 16 ms FTDI latency timer, twice, plus
  2 ms) to every packet's wire time. Here that budget is a setting: tests widen it to ride out
  pty scheduling hiccups, a tuned adapter (latency timer 1 ms) can shrink it.
- Clock: the SDK measures timeouts with ``time.time()``, so an NTP step fires or stretches a
  timeout; here it is the monotonic clock.
- Waiting: the SDK polls ``readPort`` in a tight loop while it waits for a reply (one core at
  100 %). Here ``readPort`` first sleeps in ``select`` until a byte arrives or ``idle_wait_s``
  passes, which costs no latency (select returns as soon as the port is readable).
"""

from __future__ import annotations

import fcntl
import select
import time

from dynamixel_sdk import PortHandler


class TunedPortHandler(PortHandler):  # type: ignore[misc]  # the SDK is untyped
    def __init__(self, port_name: str, latency_budget_ms: float, idle_wait_s: float = 0.001):
        super().__init__(port_name)
        self.latency_budget_ms = latency_budget_ms
        self.idle_wait_s = idle_wait_s

    def setPacketTimeout(self, packet_length: int) -> None:  # SDK method name
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = self.tx_time_per_byte * packet_length + self.latency_budget_ms

    def getCurrentTime(self) -> float:  # SDK method name
        return time.monotonic_ns() / 1_000_000.0  # milliseconds, as the SDK expects

    def readPort(self, length: int) -> bytes:  # SDK method name
        if length > 0:
            select.select([self.ser.fileno()], [], [], self.idle_wait_s)
        return bytes(self.ser.read(length))

    def lock_exclusive(self) -> None:
        """Take the port's advisory lock, as pyserial's ``exclusive=True`` does.

        The SDK's port is not thread-safe and a bus has one master: a second driver on the same
        adapter, in this process or another, would interleave packets. Raises BlockingIOError
        when someone else holds the lock; the lock goes with the file descriptor on close.
        """
        fcntl.flock(self.ser.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)

    def try_low_latency(self) -> bool:
        """Ask the kernel for the serial driver's low-latency mode; False where it has none.

        A pty (the emulator) and some USB adapters refuse the ioctl (ENOTTY): that only costs
        latency, never correctness, so it is not an error.
        """
        try:
            self.ser.set_low_latency_mode(True)
        except (ValueError, OSError, AttributeError):
            return False
        return True
