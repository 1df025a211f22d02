"""Blocking operations on one Dynamixel bus, with retries and errors that name the servo.

Everything here runs on the bus's device thread (the SDK's port is not thread-safe) and speaks
control-table counts, not radians. Errors come out as driver errors the lifecycle understands:
``DriverInitError`` for setup that cannot work, ``DriverIOError`` (LINK_LOST) when replies stop,
``DeviceFault`` when a servo reports a hardware error (CONTROLLER_FAULT) or refuses a write
(CONTROLLER_REJECT). How one packet is sent and judged lives in
:mod:`drivers.dynamixel.transactions`.

An optional gripper servo (``gripper_id``) is one more servo on the same bus: it is pinged,
configured, read and released with the joints, and its goal rides in the joints' sync write,
but only when a command asks for it: holding the arm never touches the gripper's goal.
Closing the bus switches its torque off with the joints' (a servo's safe state when the runtime
lets go of the arm): a grasp outlasts that only if the gripper's gearing holds it.

The Bus Watchdog (98) of every servo, gripper included, is cleared with checked writes (a servo
whose firmware lacks it says so), armed with one broadcast, and fed by every packet. A servo
whose watchdog expired stops and ignores the goals of sync writes without a word, so after any
silence long enough to have expired it, the next read or write first reads 98 back.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from assurance.reasons import ReasonCode
from drivers.base import DeviceFault, DriverInitError, DriverIOError, NotConnected
from drivers.dynamixel import messages, tables
from drivers.dynamixel._sdk import (
    COMM_SUCCESS,
    RETRYABLE,
    SDK_BAUD_RATES,
    GroupSyncReadLike,
    GroupSyncWriteLike,
    make_sync_write,
)
from drivers.dynamixel.port import TunedPortHandler
from drivers.dynamixel.settings import DynamixelSettings
from drivers.dynamixel.sync_read import StatusSyncRead
from drivers.dynamixel.transactions import PORT_ERRORS, BusCounters, BusTransactions
from drivers.dynamixel.units import le_bytes, to_signed

__all__ = ["PORT_ERRORS", "BusCounters", "DynamixelBus", "RawState"]


@dataclass(frozen=True, slots=True)
class RawState:
    """One sync read of the state block, sign-converted, in joint order."""

    position: tuple[int, ...]
    velocity: tuple[int, ...]
    current: tuple[int, ...]
    gripper: int | None = None
    """Present Position of the gripper servo; None on a bus without one."""


class DynamixelBus(BusTransactions):
    """One serial port and the servos on it. Call from a single thread only."""

    def __init__(self, settings: DynamixelSettings, device: str) -> None:
        super().__init__(settings, device)
        self.models: dict[int, int] = {}
        self.uses_fast_sync_read = False
        self.low_latency = False
        self._reader: GroupSyncReadLike | None = None
        self._goals: GroupSyncWriteLike | None = None
        self._goals_and_gripper: GroupSyncWriteLike | None = None
        self._torque: GroupSyncWriteLike | None = None
        self._watchdog_reader: GroupSyncReadLike | None = None
        self._watchdog_writer: GroupSyncWriteLike | None = None
        self.watchdog_units = 0
        """The Bus Watchdog value armed on every servo (0: not armed)."""
        self.goals: tuple[int, ...] | None = None
        """The joints' Goal Position last written (None with torque off): where a hold holds."""
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
        """Torque off, then position mode (Operating Mode is EEPROM: locked while torque is on).

        The gripper goes to current-based position mode with the squeeze current as its Goal
        Current: closed on a part, it stalls short of its goal, and in plain position mode it
        would push with all it has until its overload alert switches the torque off (part
        dropped, arm faulted). Goal Current is RAM: written after the mode, every connect.
        """
        self.goals = None
        with self._link_errors():
            for dxl_id in self.settings.all_ids:
                self._write_item(dxl_id, tables.TORQUE_ENABLE, 0)
            for dxl_id in self.settings.all_ids:
                mode = (tables.OperatingMode.CURRENT_BASED_POSITION
                        if dxl_id == self.settings.gripper_id else tables.OperatingMode.POSITION)
                if self._read_byte(dxl_id, tables.OPERATING_MODE) != mode:
                    # Written only when different: EEPROM has a limited number of write cycles.
                    self._write_item(dxl_id, tables.OPERATING_MODE, mode)
            if self.settings.gripper_id is not None:
                self._write_item(self.settings.gripper_id, tables.GOAL_CURRENT,
                                 self.settings.gripper_current_units)

    def hold_at_goals(self) -> tuple[int, ...]:
        """Write every joint's last goal again (the present position only if none was
        written since torque on); returns the goals held.

        Not the present position once a goal is known: a glitched reading made the goal
        would move the arm to it (0.5 rad in a takeover's holds, chasing the glitch).
        The gripper's goal stays as it is: a gripper holding a part sits wider than its goal
        (it squeezes), and making "where it is" its goal would stop the squeeze and drop it.
        """
        goals = self.goals if self.goals is not None else self.read_state().position
        self.write_goals(goals)
        return goals

    def enable_torque_holding(self) -> RawState:
        """Set every goal (gripper too) to the present position, then torque on: nothing jumps."""
        state = self.read_state()
        self.write_goals(state.position, state.gripper)
        with self._link_errors():
            for dxl_id in self.settings.all_ids:
                self._write_item(dxl_id, tables.TORQUE_ENABLE, 1)
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
        self._expect_watchdogs_alive()
        with self._link_errors():
            self._sync_read()
            reader = self._require(self._reader)
            self._check_status_errors(reader.errors)
        ids, get = self.settings.ids, reader.getData
        gripper = self.settings.gripper_id
        return RawState(
            position=tuple(to_signed(get(i, tables.PRESENT_POSITION.address, 4), 4) for i in ids),
            velocity=tuple(to_signed(get(i, tables.PRESENT_VELOCITY.address, 4), 4) for i in ids),
            current=tuple(to_signed(get(i, tables.PRESENT_CURRENT.address, 2), 2) for i in ids),
            gripper=None if gripper is None else to_signed(
                get(gripper, tables.PRESENT_POSITION.address, 4), 4),
        )

    def write_goals(self, ticks: Sequence[int], gripper: int | None = None) -> None:
        """One sync write of Goal Position to every joint, and to the gripper if ``gripper`` is
        a tick (broadcast: no reply to wait for). Without it the gripper's goal is untouched.

        Raises:
            DriverIOError: the packet could not be sent (port closed or gone).
        """
        self._expect_watchdogs_alive()
        goals = self._goal_group(gripper)
        for dxl_id, tick in zip(self.settings.ids, ticks, strict=True):
            goals.changeParam(dxl_id, le_bytes(tick, tables.GOAL_POSITION.size))
        with self._link_errors():
            self.last_sent_ns = time.monotonic_ns()
            result = goals.txPacket()
        self.counters.transactions += 1
        if result != COMM_SUCCESS:
            raise DriverIOError(self.device, f"sync write of goal positions on "
                                f"{self.settings.port} failed: {self._text(result)}")
        self.goals = tuple(ticks)

    # ------------------------------------------------------------------ bus watchdog

    def clear_watchdogs(self) -> None:
        """Bus Watchdog := 0 on every servo, checked: off, and any Bus Watchdog Error cleared
        (the only way out of it), so that goals are taken again.

        Raises:
            DriverInitError: a servo refused it (firmware older than v38 has no address 98).
        """
        with self._link_errors():
            for dxl_id in self.settings.all_ids:
                try:
                    self._write_item(dxl_id, tables.BUS_WATCHDOG, 0)
                except DeviceFault as error:
                    raise DriverInitError(self.device, messages.watchdog_unsupported(
                        self.settings.port, dxl_id, str(error), self.settings.gripper_id),
                    ) from error
        self.watchdog_units = 0

    def arm_watchdogs(self, units: int) -> None:
        """One broadcast (no reply, about 0.1 ms on the wire): every servo stops when no
        instruction packet reaches it for ``units`` × 20 ms while its torque is on."""
        writer = self._require(self._watchdog_writer)
        for dxl_id in self.settings.all_ids:
            writer.changeParam(dxl_id, [units])
        with self._link_errors():
            self.last_sent_ns = time.monotonic_ns()
            result = writer.txPacket()
        if result != COMM_SUCCESS:
            raise DriverIOError(self.device, f"sync write of the Bus Watchdog on "
                                f"{self.settings.port} failed: {self._text(result)}")
        self.watchdog_units = units

    def _expect_watchdogs_alive(self) -> None:
        """After a silence of half the watchdog time or more, read 98 back before trusting a
        sync write to be heard (host and servo clocks, and USB latency, differ by far less).

        Raises:
            DeviceFault: WATCHDOG, naming the servos whose watchdog expired.
        """
        watchdog_s = self.watchdog_units * tables.BUS_WATCHDOG_UNIT_S
        if not watchdog_s or (time.monotonic_ns() - self.last_sent_ns) * 2e-9 < watchdog_s:
            return
        reader = self._require(self._watchdog_reader)
        with self._link_errors():
            self._sync_read(reader)
        stopped = [i for i in self.settings.all_ids if to_signed(reader.getData(
            i, tables.BUS_WATCHDOG.address, 1), 1) == tables.BUS_WATCHDOG_ERROR]
        if stopped:
            raise DeviceFault(self.device, messages.watchdog_expired(
                self.settings.port, stopped, watchdog_s, self.settings.gripper_id),
                ReasonCode.WATCHDOG)

    def _goal_group(self, gripper: int | None) -> GroupSyncWriteLike:
        if gripper is None or self.settings.gripper_id is None:
            return self._require(self._goals)
        goals = self._require(self._goals_and_gripper)
        goals.changeParam(self.settings.gripper_id, le_bytes(gripper, tables.GOAL_POSITION.size))
        return goals

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
        for dxl_id in self.settings.all_ids:
            model, result, error = self._with_retries(
                lambda i=dxl_id: self._handler.ping(self._port, i))
            if result == COMM_SUCCESS:
                models[dxl_id] = model
                self._check_status_errors({dxl_id: error})
            elif result not in RETRYABLE:
                raise DriverInitError(self.device, f"ping of servo id {dxl_id} on "
                                      f"{self.settings.port} failed: {self._text(result)}")
        missing = [i for i in self.settings.all_ids if i not in models]
        if missing:
            raise DriverInitError(self.device, messages.missing_servos(
                self.settings.port, self.settings.baud, missing, models, self.settings.gripper_id))
        self._check_models(models)
        return models

    def _check_models(self, models: Mapping[int, int]) -> None:
        unknown = {i: m for i, m in models.items() if m not in tables.X_SERIES_MODELS}
        if unknown:
            listed = ", ".join(f"id {i} is model {m}" for i, m in unknown.items())
            raise DriverInitError(self.device, f"{listed} on {self.settings.port}: not an "
                                  "X-series servo this driver knows (tables.X_SERIES_MODELS)")

    def _make_groups(self) -> None:
        port, every = self._port, self.settings.all_ids
        # The gripper's state rides in the joints' read: one more slot, not one more round trip.
        reader = StatusSyncRead(port, self._handler, tables.STATE_BLOCK_START,
                                tables.STATE_BLOCK_SIZE)
        torque = make_sync_write(port, self._handler, tables.TORQUE_ENABLE.address, 1)
        for dxl_id in every:
            reader.addParam(dxl_id)
            torque.addParam(dxl_id, [0])  # only ever used to switch torque off
        self._reader, self._torque = reader, torque
        self._watchdog_reader = StatusSyncRead(port, self._handler, tables.BUS_WATCHDOG.address,
                                               tables.BUS_WATCHDOG.size)
        self._watchdog_writer = make_sync_write(port, self._handler, tables.BUS_WATCHDOG.address,
                                                tables.BUS_WATCHDOG.size)
        for dxl_id in every:
            self._watchdog_reader.addParam(dxl_id)
            self._watchdog_writer.addParam(dxl_id, [0])  # replaced before sending
        # Two goal groups, so that a write without a gripper opening leaves its goal alone.
        self._goals = self._goal_writer(self.settings.ids)
        if self.settings.gripper_id is not None:
            self._goals_and_gripper = self._goal_writer(every)

    def _goal_writer(self, ids: Sequence[int]) -> GroupSyncWriteLike:
        goals = make_sync_write(self._port, self._handler, tables.GOAL_POSITION.address, 4)
        for dxl_id in ids:
            goals.addParam(dxl_id, le_bytes(tables.CENTRE_TICK, 4))  # replaced before sending
        return goals

    def _fast_read_works(self) -> bool:
        """Firmware without Fast Sync Read ignores 0x8A: every attempt then times out."""
        reader = self._require(self._reader)
        return any(reader.fastSyncRead() == COMM_SUCCESS
                   for _ in range(self.settings.retries + 1))

    # ------------------------------------------------------------------ hot-path helpers

    def _sync_read(self, group: GroupSyncReadLike | None = None) -> None:
        reader = self._require(group or self._reader)
        read = reader.fastSyncRead if self.uses_fast_sync_read else reader.txRxPacket
        attempts = self.settings.retries + 1
        for attempt in range(attempts):
            self.last_sent_ns = time.monotonic_ns()
            result = read()
            self.counters.transactions += 1
            if result == COMM_SUCCESS:
                return
            self._count_failure(result, retrying=attempt + 1 < attempts)
            if result not in RETRYABLE:
                raise DriverIOError(self.device, f"sync read on {self.settings.port} failed: "
                                    f"{self._text(result)}")
        raise self._link_lost(result, attempts)
