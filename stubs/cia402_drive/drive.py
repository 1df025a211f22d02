"""One emulated CiA 402 servo drive: a canopen ``LocalNode`` plus what LocalNode lacks.

LocalNode brings the SDO server, NMT slave, heartbeat producer and EMCY producer. Added here:
the 402 state machine behind 0x6040/0x6041, modes of operation (0x6060/0x6061, 0x6502), the
PDO set the master configured over SDO (rebuilt on each NMT start), RPDO decoding (applied at
SYNC for synchronous RPDOs), TPDO transmission on SYNC, drive faults with EMCY, and what the
drive does when its master goes away (``supervision.py``): a heartbeat consumer (0x1016) and
the abort connection option (0x6007) on a heartbeat event, NMT STOPPED or an NMT reset.

Position counts are converted with the emulator's own encoders (``encoders.py``): radians for a
joint drive, metres of opening for a gripper drive.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from canopen import LocalNode
from canopen.objectdictionary import ODVariable
from canopen.pdo import PdoMap
from canopen.sdo import SdoAbortedError

from stubs.cia402_drive.encoders import Encoder, LinearEncoder
from stubs.cia402_drive.pdo import TpdoPacker, unsubscribe
from stubs.cia402_drive.profile import (
    ABORT_VALUE_RANGE,
    EMCY_COMMUNICATION,
    EMCY_FOLLOWING_ERROR,
    EMCY_HEARTBEAT,
    ERROR_REGISTER_COMMUNICATION,
    ERROR_REGISTER_GENERIC,
    ERROR_REGISTER_PROFILE,
    NO_FOLLOWING_LIMIT,
    SUPPORTED_MODE_BITS,
    AbortConnection,
    Index,
    Mode,
    PowerState,
    StatusBit,
)
from stubs.cia402_drive.state_machine import PowerStateMachine
from stubs.cia402_drive.supervision import REACTIONS, ConnectionLoss, HeartbeatConsumer

log = logging.getLogger(__name__)


CACHED_PARAMETERS = {
    Index.TARGET_POSITION: "target_counts",
    Index.COMM_CYCLE_PERIOD: "cycle_us",
    Index.FOLLOWING_ERROR_WINDOW: "following_window",
    Index.RATED_TORQUE: "rated_torque",
}
"""Objects the SYNC path reads every cycle, kept as attributes when the master writes them."""
LOSS_ERROR_CODES = {
    ConnectionLoss.HEARTBEAT: EMCY_HEARTBEAT,
    ConnectionLoss.NMT_STOPPED: EMCY_COMMUNICATION,
    ConnectionLoss.NMT_RESET: EMCY_COMMUNICATION,
}
"""Error code of a fault signalled on a lost connection (0x6007 = fault signal)."""


NMT_LOSSES = {"STOPPED": ConnectionLoss.NMT_STOPPED, "INITIALISING": ConnectionLoss.NMT_RESET}
"""NMT states (as canopen names them) whose entry is a lost connection for 0x6007."""
NEW_SETPOINT_WINDOW = 1e-3
"""A drive that starts following its target (OPERATION ENABLED in CSP) with the target further
than this from its axis (rad, or m for the gripper) was given a new setpoint: a motion command."""


class EmulatedDrive:
    def __init__(self, node: LocalNode, encoder: Encoder | LinearEncoder, lock: threading.RLock,
                 q0: float, following_error: float | None, max_velocity: float) -> None:
        """``q0``, ``following_error`` and ``max_velocity`` (per second) are in the encoder's
        unit (rad or m); a None ``following_error`` leaves following-error supervision off
        (0x6065 = 0xFFFFFFFF)."""
        self.node = node
        self.encoder = encoder
        self.machine = PowerStateMachine()
        self.mode = Mode.NO_MODE
        self.mode_locked = False
        """Injected: the drive accepts 0x6060 writes but never switches mode."""
        self.heartbeat_stopped = False
        self.error_code = 0
        self.error_register = 0
        self.target_counts = 0
        self.cycle_us = 0
        """0x1006 as the master wrote it: the SYNC period the drive expects."""
        self.actual = (encoder.counts(q0), 0, 0)  # position, velocity (counts), torque (‰)
        self.reported_position = self.actual[0]
        """What 0x6064 reports: the actual position, unless a reading glitch is injected."""
        self._lock = lock
        self._hold_q: float | None = q0
        self._nmt_state = node.nmt.state
        self._pending_rpdos: dict[int, PdoMap] = {}
        self._limits = (0, 0)
        self.rated_torque = int(node.sdo[Index.RATED_TORQUE].raw)
        self.following_window = float(NO_FOLLOWING_LIMIT) if following_error is None else (
            encoder.counts_per_unit * following_error)
        node.sdo[Index.FOLLOWING_ERROR_WINDOW].raw = round(self.following_window)
        node.sdo[Index.MAX_PROFILE_VELOCITY].raw = round(encoder.counts_per_unit * max_velocity)
        if isinstance(encoder, Encoder):  # a rotary axis: increments per turn, no gearbox
            node.sdo[Index.POSITION_ENCODER_RESOLUTION][1].raw = encoder.counts_per_rev
        self.motion_commands = 0
        """Commands that can move the axis: a new target while following one, or the start of
        following (enable, or a mode switch) with a target away from the axis."""
        self._setpoint_window = NEW_SETPOINT_WINDOW * encoder.counts_per_unit
        self._live: dict[int, Callable[[], int]] = {
            Index.STATUSWORD: self.statusword,
            Index.MODES_DISPLAY: lambda: int(self.mode),
            Index.POSITION_ACTUAL: lambda: self.reported_position,
            Index.VELOCITY_ACTUAL: lambda: self.actual[1],
            Index.TORQUE_ACTUAL: lambda: self.actual[2],
            Index.ERROR_CODE: lambda: self.error_code,
            Index.ERROR_REGISTER: lambda: self.error_register,
        }
        """Objects whose value is the drive's live state, not a stored parameter."""
        self._tpdos: tuple[TpdoPacker, ...] = ()
        self.consumer = HeartbeatConsumer()
        self.abort_option = AbortConnection(node.sdo[Index.ABORT_CONNECTION_OPTION].raw)
        self.connection_losses: list[ConnectionLoss] = []
        """Every lost connection the drive reacted to, in order (tests read it)."""
        self._heartbeat_error = False
        node.add_read_callback(self._on_read)
        node.add_write_callback(self._on_write)
        for pdo in node.rpdo.map.values():
            pdo.add_callback(self._on_rpdo)

    @property
    def node_id(self) -> int:
        return self.node.id

    @property
    def state(self) -> PowerState:
        return self.machine.state

    @property
    def operational(self) -> bool:
        return self.node.nmt.state == "OPERATIONAL"

    @property
    def follows_target(self) -> bool:
        """Enabled in CSP: the drive moves its axis to the target it receives every SYNC."""
        return self.machine.enabled and self.mode == Mode.CYCLIC_SYNCHRONOUS_POSITION

    # -- object dictionary ---------------------------------------------------------------------

    def statusword(self) -> int:
        word = self.machine.statusword_bits() | StatusBit.REMOTE
        if self.follows_target:
            word |= StatusBit.FOLLOWS_COMMAND
        return word

    def _on_read(self, index: int, subindex: int, od: object) -> int | None:
        live = self._live.get(index)
        if live is None:
            return None
        with self._lock:
            return live()

    def _on_write(self, index: int, subindex: int, od: object, data: bytes) -> None:
        value = od.decode_raw(data)  # type: ignore[attr-defined]
        with self._lock:
            following, target = self.follows_target, self.target_counts
            self._apply_write(index, subindex, value)
            self._count_motion(following, target)

    def _apply_write(self, index: int, subindex: int, value: int) -> None:
        if index in CACHED_PARAMETERS:
            setattr(self, CACHED_PARAMETERS[index], value)
        elif index == Index.CONTROLWORD:
            self._on_controlword(value)
        elif index == Index.MODES_OF_OPERATION:
            self._on_mode(value)
        elif index == Index.QUICK_STOP_OPTION:
            self.machine.quick_stop_option = value
        elif index == Index.ABORT_CONNECTION_OPTION:
            self.abort_option = _abort_option(value)
        elif index == Index.HEARTBEAT_CONSUMER:
            self._on_consumer(value)
        elif index == Index.SOFTWARE_LIMITS:
            low, high = self._limits
            self._limits = (value, high) if subindex == 1 else (low, value)
        elif index == Index.HEARTBEAT_TIME and self.heartbeat_stopped:
            self.node.nmt.stop_heartbeat()  # LocalNode just restarted it; stay silent

    def _count_motion(self, was_following: bool, old_target: int) -> None:
        """Count a write that can move the axis (see ``motion_commands``)."""
        if not self.follows_target:
            return
        if was_following:
            if self.target_counts != old_target:
                self.motion_commands += 1
        elif abs(self.target_counts - self.actual[0]) > self._setpoint_window:
            self.motion_commands += 1

    def _on_controlword(self, controlword: int) -> None:
        was_enabled = self.machine.enabled
        if self.machine.on_controlword(controlword):
            self.error_code = self.error_register = 0
            self.node.emcy.reset()  # EMCY 0x0000: the fault is gone
        if was_enabled and not self.machine.enabled:
            self._hold_q = None  # brake where the joint is now

    def _on_consumer(self, entry: int) -> None:
        try:
            self.consumer.configure(entry)
        except ValueError as error:
            raise SdoAbortedError(ABORT_VALUE_RANGE) from error

    def _on_mode(self, mode: int) -> None:
        if mode not in {Mode.NO_MODE, *SUPPORTED_MODE_BITS}:
            raise SdoAbortedError(ABORT_VALUE_RANGE)  # as a drive does for a mode it lacks
        if not self.mode_locked:
            self.mode = Mode(mode)

    # -- faults --------------------------------------------------------------------------------

    def fault(self, code: int, register: int = ERROR_REGISTER_GENERIC) -> None:
        """A drive fault: FAULT, error code and register latched, EMCY sent (unless NMT
        STOPPED, where a node sends only its heartbeat: CiA 301)."""
        with self._lock:
            self.machine.fault()
            self._hold_q = None
            self.error_code = code
            self.error_register = register | ERROR_REGISTER_GENERIC  # set with any error
            if self.node.nmt.state != "STOPPED":
                self.node.emcy.send(code, self.error_register)

    # -- a lost master (supervision.py) --------------------------------------------------------

    def on_heartbeat(self, producer: int, now: float) -> None:
        """Some node's heartbeat (or boot-up) was received."""
        self.consumer.heard(producer, now)
        if self._heartbeat_error and self.consumer.last_heard is not None:
            self._heartbeat_error = False  # the heartbeat event is resolved
            if self.machine.state is not PowerState.FAULT:  # a fault stays until its reset
                self.error_register = 0
                self.node.emcy.reset()

    def supervise(self, now: float) -> None:
        """The drive's heartbeat event, if its consumer is overdue (the emulator's clock calls
        this under its lock, once no received frame waits to be handled)."""
        if self.consumer.overdue(now):
            self.consumer.expire()
            self.connection_lost(ConnectionLoss.HEARTBEAT)

    def connection_lost(self, loss: ConnectionLoss) -> None:
        """React as 0x6007 says. A heartbeat event is also an EMCY (0x8130), and takes an
        OPERATIONAL drive to PRE-OPERATIONAL: CiA 301's error behaviour for a communication
        error where 0x1029 is not implemented (as here); its PDOs stop with it."""
        self.connection_losses.append(loss)
        if loss is ConnectionLoss.HEARTBEAT:
            self._heartbeat_error = True
            if self.operational:
                self.node.nmt.state = "PRE-OPERATIONAL"
                self._nmt_state = self.node.nmt.state
        if self.abort_option is AbortConnection.FAULT_SIGNAL:
            self.fault(LOSS_ERROR_CODES[loss], ERROR_REGISTER_COMMUNICATION)
            return
        if loss is ConnectionLoss.HEARTBEAT:
            self.error_register |= ERROR_REGISTER_COMMUNICATION | ERROR_REGISTER_GENERIC
            self.node.emcy.send(EMCY_HEARTBEAT, self.error_register)
        command = REACTIONS[self.abort_option]
        if command is not None:
            was_enabled = self.machine.enabled
            self.machine.apply(command)
            if was_enabled and not self.machine.enabled:
                self._hold_q = None  # brake where the joint is now

    def stop_heartbeat(self) -> None:
        self.heartbeat_stopped = True
        self.node.nmt.stop_heartbeat()

    def restart_heartbeat(self) -> None:
        self.heartbeat_stopped = False
        self.node.nmt.start_heartbeat(self.node.sdo[Index.HEARTBEAT_TIME].raw)

    # -- PDOs ----------------------------------------------------------------------------------

    def on_nmt(self) -> None:
        """After an NMT command: entering OPERATIONAL activates the PDO set written over SDO;
        entering STOPPED, or a reset (canopen's NMT slave then reports INITIALISING), is a lost
        connection (what the reset itself would do next is not emulated)."""
        state, previous = self.node.nmt.state, self._nmt_state
        self._nmt_state = state
        if state == previous:
            return
        if state == "OPERATIONAL":
            self._rebuild_pdos()
        elif state in NMT_LOSSES:
            self.connection_lost(NMT_LOSSES[state])

    def _rebuild_pdos(self) -> None:
        network = self.node.network
        for pdo in [*self.node.rpdo.map.values(), *self.node.tpdo.map.values()]:
            if pdo.cob_id is not None:
                unsubscribe(network, pdo)
        self.node.rpdo.read()
        self.node.tpdo.read()
        for pdo in self.node.tpdo.map.values():
            unsubscribe(network, pdo)  # our own TPDOs come back on an echoing bus
        self._tpdos = tuple(
            TpdoPacker.from_map(pdo) for pdo in self.node.tpdo.map.values()
            if pdo.enabled and pdo.trans_type is not None and pdo.trans_type <= 240
        )  # event-driven TPDOs (254/255) are not produced by this emulator
        self._pending_rpdos.clear()

    def _on_rpdo(self, pdo: PdoMap) -> None:
        if not self.operational:
            return
        if pdo.trans_type is not None and pdo.trans_type <= 240:
            with self._lock:
                self._pending_rpdos[pdo.cob_id or 0] = pdo  # the last one before SYNC wins
        else:
            self._apply_rpdo(pdo)

    def _apply_rpdo(self, pdo: PdoMap) -> None:
        for var in pdo:
            if not var.length:
                continue
            try:
                self.node.set_data(var.index, var.subindex, var.get_data())
            except SdoAbortedError as error:
                log.warning("node %d: RPDO value for 0x%04X refused: %s", self.node_id,
                            var.index, error)

    def apply_pending_rpdos(self) -> None:
        pending, self._pending_rpdos = list(self._pending_rpdos.values()), {}
        for pdo in pending:
            self._apply_rpdo(pdo)

    def transmit_tpdos(self, sync_count: int) -> None:
        for packer in self._tpdos:
            if sync_count % packer.every == 0:
                self.node.network.send_message(packer.cob_id, packer.pack(self._value))

    def _value(self, od: ODVariable) -> int:
        live = self._live.get(od.index)
        if live is not None:
            return live()
        return od.decode_raw(self.node.get_data(od.index, od.subindex))

    # -- motion (called at SYNC, under the emulator lock) ---------------------------------------

    def joint_target(self, q_now: float) -> float:
        """Where the plant should take this joint: the CSP target, or a held position."""
        if self.follows_target:
            self._hold_q = None
            return self.encoder.position(self._limited(self.target_counts))
        if self._hold_q is None:
            self._hold_q = q_now  # brake (or quick-stop) position: where it was when it stopped
        return self._hold_q

    def _limited(self, counts: int) -> int:
        low, high = self._limits
        return min(max(counts, low), high) if low < high else counts

    def update_actual(self, q: float, qd: float, effort: float, glitch: float = 0.0) -> None:
        """The axis's new state; ``glitch``: an injected offset of what it reports (the
        drive's own supervision keeps using the true position)."""
        position = self.encoder.counts(q)
        self.reported_position = self.encoder.counts(q + glitch) if glitch else position
        velocity = round(qd * self.encoder.direction * self.encoder.counts_per_unit)
        torque = round(1e6 * effort * self.encoder.direction / max(self.rated_torque, 1))
        self.actual = (position, velocity, max(-32768, min(32767, torque)))
        self._check_following_error(position)
        if abs(qd) < 1e-3:
            self.machine.after_standstill()

    def _check_following_error(self, position: int) -> None:
        if not self.follows_target or self.following_window >= NO_FOLLOWING_LIMIT:
            return
        if abs(self._limited(self.target_counts) - position) > self.following_window:
            self.fault(EMCY_FOLLOWING_ERROR, ERROR_REGISTER_PROFILE)


def _abort_option(value: int) -> AbortConnection:
    """0x6007 as written; this drive has no manufacturer-specific (negative) reactions."""
    try:
        return AbortConnection(value)
    except ValueError as error:
        raise SdoAbortedError(ABORT_VALUE_RANGE) from error
