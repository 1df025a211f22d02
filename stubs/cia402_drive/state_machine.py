"""The CiA 402 device-control state machine of one drive: controlword in, state out (pure).

Transitions are numbered as in CiA 402-2, figure 12. The emulator calls ``on_controlword`` for
every controlword it receives (SDO or RPDO), ``fault`` when a drive fault occurs and
``quick_stop_input`` for a quick stop the drive makes on its own.
"""

from __future__ import annotations

from stubs.cia402_drive.profile import STATE_STATUS, ControlBit, PowerState, StatusBit
from stubs.cia402_drive.profile import DeviceCommand as Command

S = PowerState
TRANSITIONS: dict[tuple[PowerState, Command], PowerState] = {
    (S.SWITCH_ON_DISABLED, Command.SHUTDOWN): S.READY_TO_SWITCH_ON,  # 2
    (S.READY_TO_SWITCH_ON, Command.SWITCH_ON): S.SWITCHED_ON,  # 3
    (S.READY_TO_SWITCH_ON, Command.ENABLE_OPERATION): S.OPERATION_ENABLED,  # 3 then 4
    (S.READY_TO_SWITCH_ON, Command.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 7
    (S.READY_TO_SWITCH_ON, Command.QUICK_STOP): S.SWITCH_ON_DISABLED,  # 7
    (S.SWITCHED_ON, Command.ENABLE_OPERATION): S.OPERATION_ENABLED,  # 4
    (S.SWITCHED_ON, Command.SHUTDOWN): S.READY_TO_SWITCH_ON,  # 6
    (S.SWITCHED_ON, Command.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 10
    (S.SWITCHED_ON, Command.QUICK_STOP): S.SWITCH_ON_DISABLED,  # 10
    (S.OPERATION_ENABLED, Command.SWITCH_ON): S.SWITCHED_ON,  # 5 (disable operation)
    (S.OPERATION_ENABLED, Command.SHUTDOWN): S.READY_TO_SWITCH_ON,  # 8
    (S.OPERATION_ENABLED, Command.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 9
    (S.OPERATION_ENABLED, Command.QUICK_STOP): S.QUICK_STOP_ACTIVE,  # 11
    (S.QUICK_STOP_ACTIVE, Command.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 12
}
RESUMABLE_QUICK_STOP = range(5, 9)
"""0x605A values after which the drive stays in QUICK STOP ACTIVE and may resume (16)."""


def decode_command(controlword: int) -> Command | None:
    """The device-control command in a controlword (bits 0-3, CiA 402-2 table 31); None while
    the fault-reset bit is set (a reset is its rising edge, handled on its own)."""
    bits = ControlBit(controlword & 0xFF)
    if ControlBit.FAULT_RESET in bits:
        return None
    if ControlBit.ENABLE_VOLTAGE not in bits:
        return Command.DISABLE_VOLTAGE
    if ControlBit.QUICK_STOP not in bits:  # active low
        return Command.QUICK_STOP
    if ControlBit.SWITCH_ON not in bits:
        return Command.SHUTDOWN
    if ControlBit.ENABLE_OPERATION not in bits:
        return Command.SWITCH_ON
    return Command.ENABLE_OPERATION


class PowerStateMachine:
    def __init__(self) -> None:
        self.state = PowerState.SWITCH_ON_DISABLED  # transitions 0 and 1 happen at boot
        self.quick_stop_option = 2
        self.quick_stop_input_active = False
        """A quick stop the drive makes itself (its input) holds until the input is released."""
        self._last_controlword = 0

    def on_controlword(self, controlword: int, fault_cleared: bool = True) -> bool:
        """Apply one controlword; True if it was a fault reset that left FAULT (15)."""
        reset = ControlBit.FAULT_RESET
        rising_reset = bool(controlword & reset) and not self._last_controlword & reset
        self._last_controlword = controlword
        if self.state is S.FAULT:
            if rising_reset and fault_cleared:
                self.state = S.SWITCH_ON_DISABLED
                return True
            return False
        command = decode_command(controlword)
        if command is None:
            return False
        if (self.state, command) == (S.QUICK_STOP_ACTIVE, Command.ENABLE_OPERATION):
            if self.quick_stop_option in RESUMABLE_QUICK_STOP and not self.quick_stop_input_active:
                self.state = S.OPERATION_ENABLED  # 16
            return False
        self.state = TRANSITIONS.get((self.state, command), self.state)
        return False

    def fault(self) -> None:
        """Fault reaction is instantaneous here: straight to FAULT (13, 14)."""
        self.state = S.FAULT

    def quick_stop_input(self, active: bool = True) -> None:
        self.quick_stop_input_active = active
        if active and self.state is S.OPERATION_ENABLED:
            self.state = S.QUICK_STOP_ACTIVE

    def after_standstill(self) -> None:
        """With a non-resumable quick-stop option the drive disables itself once stopped."""
        if self.state is S.QUICK_STOP_ACTIVE and self.quick_stop_option not in (
            RESUMABLE_QUICK_STOP
        ):
            self.state = S.SWITCH_ON_DISABLED

    @property
    def enabled(self) -> bool:
        return self.state is S.OPERATION_ENABLED

    def statusword_bits(self) -> StatusBit:
        return STATE_STATUS[self.state]

