"""Blocking operations on one Dynamixel bus, with retries and errors that name the servo.

Everything here runs on the bus's device thread (the SDK's port is not thread-safe) and speaks
control-table counts, not radians. Errors come out as driver errors the lifecycle understands:
``DriverInitError`` for setup that cannot work, ``DriverIOError`` (LINK_LOST) when replies stop,
``DeviceFault`` when a servo reports a hardware error (CONTROLLER_FAULT) or refuses a write
(CONTROLLER_REJECT).
"""

from __future__ import annotations

import contextlib
import termios
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import TypeVar

from assurance.reasons import ReasonCode
from drivers.base import DeviceFault, DriverInitError, DriverIOError, NotConnected
from drivers.dynamixel import messages, tables
from drivers.dynamixel._sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    RETRYABLE,
    SDK_BAUD_RATES,
    GroupSyncReadLike,
    GroupSyncWriteLike,
    make_packet_handler,
    make_sync_write,
)
from drivers.dynamixel.port import TunedPortHandler
from drivers.dynamixel.settings import DynamixelSettings
from drivers.dynamixel.sync_read import StatusSyncRead
from drivers.dynamixel.units import le_bytes, to_signed

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


@dataclass(frozen=True, slots=True)
class RawState:
    """One sync read of the state block, sign-converted, in joint order."""

    position: tuple[int, ...]
    velocity: tuple[int, ...]
    current: tuple[int, ...]


class DynamixelBus:
    """One serial port and the servos on it. Call from a single thread only."""

    def __init__(self, settings: DynamixelSettings, device: str) -> None:
        self.settings = settings
        self.device = device
        self.counters = BusCounters()
        self.models: dict[int, int] = {}
        self.uses_fast_sync_read = False
        self.low_latency = False
        self._handler = make_packet_handler()
        self._port: TunedPortHandler | None = None
        self._reader: GroupSyncReadLike | None = None
        self._goals: GroupSyncWriteLike | None = None
        self._torque: GroupSyncWriteLike | None = None
        self._abandoned = False

    # ------------------------------------------------------------------ lifecycle

    def connect(self) -> None:
        """Open the port, find every servo, and pick fast sync read if the servos support it.

        Raises:
            DriverInitError: bad port path or baud rate, port taken, a servo missing or not
                X-series; the message names the port, the ids and the setting to check.
            DeviceFault: a servo already reports a hardware error.
        """
        self._open_port()
        try:
            with self._link_errors():
                self.models = self._identify_servos()
                self._make_groups()
                self.uses_fast_sync_read = (self.settings.fast_sync_read
                                            and self._fast_read_works())
        except BaseException:
            self.close_port()
            raise
        if self._abandoned:  # the caller gave up waiting: do not leave the port open and locked
            self.close_port()
            raise NotConnected(self.device, f"connect to {self.settings.port} was abandoned")

    def prepare_position_mode(self) -> None:
        """Torque off, then position mode (Operating Mode is EEPROM: locked while torque is on)."""
        with self._link_errors():
            for dxl_id in self.settings.ids:
                self._write_byte(dxl_id, tables.TORQUE_ENABLE, 0)
            for dxl_id in self.settings.ids:
                if self._read_byte(dxl_id, tables.OPERATING_MODE) != tables.OperatingMode.POSITION:
                    # Written only when different: EEPROM has a limited number of write cycles.
                    self._write_byte(dxl_id, tables.OPERATING_MODE, tables.OperatingMode.POSITION)

    def hold_here(self) -> RawState:
        """Make the present position every servo's goal; returns the state it read."""
        state = self.read_state()
        self.write_goals(state.position)
        return state

    def enable_torque_holding(self) -> RawState:
        """Set every goal to the present position, then switch torque on: nothing jumps."""
        state = self.hold_here()
        with self._link_errors():
            for dxl_id in self.settings.ids:
                self._write_byte(dxl_id, tables.TORQUE_ENABLE, 1)
        return state

    def release(self) -> None:
        """Torque off on every servo with one broadcast packet, then close the port.

        A broadcast gets no reply, so a silent or faulted servo cannot make closing hang.
        """
        try:
            if self._torque is not None and self._port is not None and self._port.is_open:
                with contextlib.suppress(*PORT_ERRORS):
                    self._torque.txPacket()
        finally:
            self.close_port()

    def abandon(self) -> None:
        """From another thread, after a call on this bus missed its deadline.

        Closing the port under the stuck worker makes its SDK call fail fast instead of holding
        the device (and its lock) open; a connect still in progress closes it when it ends.
        """
        self._abandoned = True
        self.close_port()

    def close_port(self) -> None:
        port, self._port = self._port, None
        if port is not None and port.is_open:
            with contextlib.suppress(*PORT_ERRORS):
                port.closePort()

    # ------------------------------------------------------------------ hot path

    def read_state(self) -> RawState:
        """Present current, velocity and position of every servo in one (fast) sync read.

        Raises:
            DriverIOError: no good reply after ``retries`` extra attempts (LINK_LOST); the
                message names the servos that stopped answering.
            DeviceFault: a status packet carried the alert bit (CONTROLLER_FAULT, with the
                Hardware Error Status bits named) or an error number (CONTROLLER_REJECT).
        """
        with self._link_errors():
            self._sync_read()
            reader = self._require(self._reader)
            self._check_status_errors(reader.errors)
        ids, get = self.settings.ids, reader.getData
        return RawState(
            position=tuple(to_signed(get(i, tables.PRESENT_POSITION.address, 4), 4) for i in ids),
            velocity=tuple(to_signed(get(i, tables.PRESENT_VELOCITY.address, 4), 4) for i in ids),
            current=tuple(to_signed(get(i, tables.PRESENT_CURRENT.address, 2), 2) for i in ids),
        )

    def write_goals(self, ticks: Sequence[int]) -> None:
        """One sync write of Goal Position to every servo (broadcast: no reply to wait for).

        Raises:
            DriverIOError: the packet could not be sent (port closed or gone).
        """
        goals = self._require(self._goals)
        for dxl_id, tick in zip(self.settings.ids, ticks, strict=True):
            goals.changeParam(dxl_id, le_bytes(tick, tables.GOAL_POSITION.size))
        with self._link_errors():
            result = goals.txPacket()
        self.counters.transactions += 1
        if result != COMM_SUCCESS:
            raise DriverIOError(self.device, f"sync write of goal positions on "
                                f"{self.settings.port} failed: {self._text(result)}")

    # ------------------------------------------------------------------ connect helpers

    def _open_port(self) -> None:
        port = TunedPortHandler(self.settings.port, self.settings.latency_budget_ms)
        baud = self.settings.baud
        if port.getCFlagBaud(baud) <= 0:
            rates = ", ".join(str(rate) for rate in SDK_BAUD_RATES)
            raise DriverInitError(self.device, f"baud rate {baud} for {self.settings.port} is "
                                  f"not one dynamixel_sdk supports ({rates}); check `baud`")
        try:
            port.setBaudRate(baud)  # opens the port at that rate
        except OSError as error:  # serial.SerialException is an OSError
            raise DriverInitError(self.device, f"cannot open serial port {self.settings.port}: "
                                  f"{error}; check `port` (adapter plugged in? udev rule? "
                                  "user in the dialout group?)") from error
        try:
            port.lock_exclusive()
        except BlockingIOError as error:
            port.closePort()
            raise DriverInitError(self.device, f"{self.settings.port} is already in use by "
                                  "another driver or program; a bus has one master") from error
        self.low_latency = port.try_low_latency()
        self._port = port

    def _identify_servos(self) -> dict[int, int]:
        models: dict[int, int] = {}
        for dxl_id in self.settings.ids:
            model, result, error = self._with_retries(
                lambda i=dxl_id: self._handler.ping(self._port, i))
            if result == COMM_SUCCESS:
                models[dxl_id] = model
                self._check_status_errors({dxl_id: error})
            elif result not in RETRYABLE:
                raise DriverInitError(self.device, f"ping of servo id {dxl_id} on "
                                      f"{self.settings.port} failed: {self._text(result)}")
        missing = [i for i in self.settings.ids if i not in models]
        if missing:
            raise DriverInitError(self.device, messages.missing_servos(
                self.settings.port, self.settings.baud, missing, models))
        self._check_models(models)
        return models

    def _check_models(self, models: Mapping[int, int]) -> None:
        unknown = {i: m for i, m in models.items() if m not in tables.X_SERIES_MODELS}
        if unknown:
            listed = ", ".join(f"id {i} is model {m}" for i, m in unknown.items())
            raise DriverInitError(self.device, f"{listed} on {self.settings.port}: not an "
                                  "X-series servo this driver knows (tables.X_SERIES_MODELS)")

    def _make_groups(self) -> None:
        port, ids = self._port, self.settings.ids
        reader = StatusSyncRead(port, self._handler, tables.STATE_BLOCK_START,
                                tables.STATE_BLOCK_SIZE)
        goals = make_sync_write(port, self._handler, tables.GOAL_POSITION.address, 4)
        torque = make_sync_write(port, self._handler, tables.TORQUE_ENABLE.address, 1)
        for dxl_id in ids:
            reader.addParam(dxl_id)
            goals.addParam(dxl_id, le_bytes(tables.CENTRE_TICK, 4))  # replaced before sending
            torque.addParam(dxl_id, [0])  # only ever used to switch torque off
        self._reader, self._goals, self._torque = reader, goals, torque

    def _fast_read_works(self) -> bool:
        """Firmware without Fast Sync Read ignores 0x8A: every attempt then times out."""
        reader = self._require(self._reader)
        return any(reader.fastSyncRead() == COMM_SUCCESS
                   for _ in range(self.settings.retries + 1))

    # ------------------------------------------------------------------ transactions

    def _sync_read(self) -> None:
        reader = self._require(self._reader)
        read = reader.fastSyncRead if self.uses_fast_sync_read else reader.txRxPacket
        attempts = self.settings.retries + 1
        for attempt in range(attempts):
            result = read()
            self.counters.transactions += 1
            if result == COMM_SUCCESS:
                return
            self._count_failure(result, retrying=attempt + 1 < attempts)
            if result not in RETRYABLE:
                raise DriverIOError(self.device, f"sync read on {self.settings.port} failed: "
                                    f"{self._text(result)}")
        raise self._link_lost(result, attempts)

    def _link_lost(self, result: int, attempts: int) -> DriverIOError:
        """Name the servos that stopped answering: one ping each, only once the link is lost."""
        pings = {i: self._handler.ping(self._port, i)[1] for i in self.settings.ids}
        silent = [i for i, answer in pings.items() if answer == COMM_RX_TIMEOUT]
        garbled = [i for i, answer in pings.items() if answer == COMM_RX_CORRUPT]
        message = messages.link_lost(self.settings.port, attempts, self._text(result), silent,
                                     garbled)
        return DriverIOError(self.device, message, ReasonCode.LINK_LOST)

    def _with_retries(self, call: SdkCall) -> tuple[int, int, int]:
        attempts = self.settings.retries + 1
        for attempt in range(attempts):
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

    def _write_byte(self, dxl_id: int, register: tables.Register, value: int) -> None:
        def write() -> tuple[int, int, int]:
            return (0, *self._handler.write1ByteTxRx(self._port, dxl_id, register.address, value))

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

    # ------------------------------------------------------------------ status errors

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
        return DeviceFault(self.device, messages.hardware_error(self.settings.port, statuses),
                           ReasonCode.CONTROLLER_FAULT)

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

