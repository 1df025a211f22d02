"""Single transactions on a Dynamixel bus: retries, the status error byte, and what failed.

:class:`BusTransactions` is the base of :class:`drivers.dynamixel.bus.DynamixelBus`: it knows
how to send one packet and judge its reply (retry a late or garbled one, turn the alert bit into
a named hardware error, a refusal into CONTROLLER_REJECT, a vanished adapter into LINK_LOST),
while the bus decides which packets to send. Everything here runs on the bus's device thread.
"""

from __future__ import annotations

import contextlib
import termios
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import TypeVar

from assurance.reasons import ReasonCode
from drivers.base import DeviceFault, DriverIOError, NotConnected
from drivers.dynamixel import messages, tables
from drivers.dynamixel._sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    RETRYABLE,
    make_packet_handler,
)
from drivers.dynamixel.port import TunedPortHandler
from drivers.dynamixel.settings import DynamixelSettings
from drivers.dynamixel.units import to_signed, to_unsigned

T = TypeVar("T")

PORT_ERRORS = (OSError, termios.error)
"""What a vanished adapter raises from inside the SDK: pyserial's SerialException is an OSError,
but the ``tcflush`` behind ``clearPort`` lets ``termios.error`` (EIO) through unwrapped."""

SdkCall = Callable[[], tuple[int, int, int]]
"""An SDK transaction normalised to (value, comm_result, status_error)."""


@dataclass(slots=True)
class BusCounters:
    transactions: int = 0
    retries: int = 0
    timeouts: int = 0
    corrupt: int = 0


class BusTransactions:
    """One port's packet handler, with retries and errors that name the servo."""

    def __init__(self, settings: DynamixelSettings, device: str) -> None:
        self.settings = settings
        self.device = device
        self.counters = BusCounters()
        self._handler = make_packet_handler()
        self._port: TunedPortHandler | None = None
        self.last_sent_ns = 0
        """When the last instruction packet went out (what the servos' Bus Watchdog counts)."""

    # ------------------------------------------------------------------ transactions

    def _with_retries(self, call: SdkCall) -> tuple[int, int, int]:
        attempts = self.settings.retries + 1
        for attempt in range(attempts):
            self.last_sent_ns = time.monotonic_ns()
            value, result, error = call()
            self.counters.transactions += 1
            if result not in RETRYABLE:
                break
            self._count_failure(result, retrying=attempt + 1 < attempts)
        return value, result, error

    def _read_byte(self, dxl_id: int, register: tables.Register) -> int:
        value, result, error = self._with_retries(
            lambda: self._handler.read1ByteTxRx(self._port, dxl_id, register.address))
        self._require_answer(dxl_id, f"reading {register.name}", result)
        self._check_status_errors({dxl_id: error})
        return value

    def read_item(self, dxl_id: int, register: tables.Register) -> int:
        """One control-table item of one servo, sign-converted (for inspection: retried, the
        status error byte checked like any read).

        Raises:
            DriverIOError: the servo did not answer.
            DeviceFault: its status packet carried an error.
        """
        read = {1: self._handler.read1ByteTxRx, 2: self._handler.read2ByteTxRx,
                4: self._handler.read4ByteTxRx}[register.size]
        with self._link_errors():
            value, result, error = self._with_retries(
                lambda: read(self._port, dxl_id, register.address))
        self._require_answer(dxl_id, f"reading {register.name}", result)
        self._check_status_errors({dxl_id: error}, f"reading {register.name}")
        return to_signed(value, register.size) if register.signed else value

    def _write_item(self, dxl_id: int, register: tables.Register, value: int) -> None:
        """Write one 1- or 2-byte item (a negative value as two's complement) and check it."""
        write_item = {1: self._handler.write1ByteTxRx, 2: self._handler.write2ByteTxRx}[
            register.size]
        raw = to_unsigned(value, register.size)

        def write() -> tuple[int, int, int]:
            return (0, *write_item(self._port, dxl_id, register.address, raw))

        _, result, error = self._with_retries(write)
        action = f"writing {value} to {register.name}"
        self._require_answer(dxl_id, action, result)
        self._check_status_errors({dxl_id: error}, action)

    def _require_answer(self, dxl_id: int, action: str, result: int) -> None:
        if result == COMM_SUCCESS:
            return
        if result in RETRYABLE:
            raise DriverIOError(self.device, f"servo id {dxl_id} on {self.settings.port} did not "
                                f"answer {action} ({self.settings.retries + 1} attempts, last: "
                                f"{self._text(result)}); check its power and cable")
        raise DriverIOError(self.device, f"{action} on servo id {dxl_id} failed: "
                            f"{self._text(result)}")

    # ------------------------------------------------------------------ diagnosis

    def _link_lost(self, result: int, attempts: int) -> DriverIOError:
        """Name the servos that stopped answering: one ping each, only once the link is lost."""
        pings = {i: self._handler.ping(self._port, i)[1] for i in self.settings.all_ids}
        silent = [i for i, answer in pings.items() if answer == COMM_RX_TIMEOUT]
        garbled = [i for i, answer in pings.items() if answer == COMM_RX_CORRUPT]
        message = messages.link_lost(self.settings.port, attempts, self._text(result), silent,
                                     garbled, self.settings.gripper_id)
        return DriverIOError(self.device, message, ReasonCode.LINK_LOST)

    def _check_status_errors(self, errors: Mapping[int, int], action: str = "") -> None:
        alerted = [i for i, error in errors.items() if error & tables.ERRBIT_ALERT]
        if alerted:
            raise self._hardware_fault(alerted)
        refused = {i: error for i, error in errors.items() if error & ~tables.ERRBIT_ALERT}
        for dxl_id, error in refused.items():
            what = action or "the state read"
            raise DeviceFault(self.device, f"servo id {dxl_id} on {self.settings.port} refused "
                              f"{what}: {self._handler.getRxPacketError(error)}",
                              ReasonCode.CONTROLLER_REJECT)

    def _hardware_fault(self, ids: Sequence[int]) -> DeviceFault:
        """Read Hardware Error Status of each alerting servo and name the bits."""
        statuses: dict[int, int | None] = {}
        for dxl_id in ids:
            status, result, _ = self._with_retries(lambda i=dxl_id: self._handler.read1ByteTxRx(
                self._port, i, tables.HARDWARE_ERROR_STATUS.address))
            statuses[dxl_id] = status if result == COMM_SUCCESS else None
        message = messages.hardware_error(self.settings.port, statuses, self.settings.gripper_id)
        return DeviceFault(self.device, message, ReasonCode.CONTROLLER_FAULT)

    # ------------------------------------------------------------------ small helpers

    @contextlib.contextmanager
    def _link_errors(self) -> Iterator[None]:
        """A port error inside the SDK means the adapter went away (unplugged, port closed)."""
        try:
            yield
        except PORT_ERRORS as error:
            raise DriverIOError(self.device, f"serial port {self.settings.port} failed: "
                                f"{error}", ReasonCode.LINK_LOST) from error

    def _count_failure(self, result: int, retrying: bool) -> None:
        self.counters.timeouts += result == COMM_RX_TIMEOUT
        self.counters.corrupt += result == COMM_RX_CORRUPT
        self.counters.retries += retrying

    def _require(self, group: T | None) -> T:
        if group is None or self._port is None:
            raise NotConnected(self.device, f"bus {self.settings.port} is not connected")
        return group

    def _text(self, result: int) -> str:
        return str(self._handler.getTxRxResult(result))
