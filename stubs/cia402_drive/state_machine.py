"""The CiA 402 device-control state machine of one drive: controlword in, state out (pure).

Transitions are numbered as in CiA 402-2, figure 12. The emulator calls ``on_controlword`` for
every controlword it receives (SDO or RPDO), ``fault`` when a drive fault occurs,
``quick_stop_input`` for a quick stop the drive makes on its own, and ``apply`` for a command
the drive gives itself (0x6007, on a lost connection).
"""

from __future__ import annotations

from stubs.cia402_drive.profile import (
    STATE_STATUS,
    ControlBit,
    DeviceCommand,
    PowerState,
)

S = PowerState
TRANSITIONS: dict[tuple[PowerState, DeviceCommand], PowerState] = {
    (S.SWITCH_ON_DISABLED, DeviceCommand.SHUTDOWN): S.READY_TO_SWITCH_ON,  # 2
    (S.READY_TO_SWITCH_ON, DeviceCommand.SWITCH_ON): S.SWITCHED_ON,  # 3
    (S.READY_TO_SWITCH_ON, DeviceCommand.ENABLE_OPERATION): S.OPERATION_ENABLED,  # 3 then 4
    (S.READY_TO_SWITCH_ON, DeviceCommand.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 7
    (S.READY_TO_SWITCH_ON, DeviceCommand.QUICK_STOP): S.SWITCH_ON_DISABLED,  # 7
    (S.SWITCHED_ON, DeviceCommand.ENABLE_OPERATION): S.OPERATION_ENABLED,  # 4
    (S.SWITCHED_ON, DeviceCommand.SHUTDOWN): S.READY_TO_SWITCH_ON,  # 6
    (S.SWITCHED_ON, DeviceCommand.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 10
    (S.SWITCHED_ON, DeviceCommand.QUICK_STOP): S.SWITCH_ON_DISABLED,  # 10
    (S.OPERATION_ENABLED, DeviceCommand.SWITCH_ON): S.SWITCHED_ON,  # 5 (disable operation)
    (S.OPERATION_ENABLED, DeviceCommand.SHUTDOWN): S.READY_TO_SWITCH_ON,  # 8
    (S.OPERATION_ENABLED, DeviceCommand.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 9
    (S.OPERATION_ENABLED, DeviceCommand.QUICK_STOP): S.QUICK_STOP_ACTIVE,  # 11
    (S.QUICK_STOP_ACTIVE, DeviceCommand.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 12
}
RESUMABLE_QUICK_STOP = range(5, 9)
"""0x605A values after which the drive stays in QUICK STOP ACTIVE and may resume (16)."""


def decode_command(controlword: int) -> DeviceCommand | None:
    """The device-control command in a controlword (bits 0-3, CiA 402-2 table 31); None while
    the fault-reset bit is set (a reset is its rising edge, handled on its own)."""
    if controlword & ControlBit.FAULT_RESET:
        return None
    if not controlword & ControlBit.ENABLE_VOLTAGE:
        return DeviceCommand.DISABLE_VOLTAGE
    if not controlword & ControlBit.QUICK_STOP:  # active low
        return DeviceCommand.QUICK_STOP
    if not controlword & ControlBit.SWITCH_ON:
        return DeviceCommand.SHUTDOWN
    if not controlword & ControlBit.ENABLE_OPERATION:
        return DeviceCommand.SWITCH_ON
    return DeviceCommand.ENABLE_OPERATION


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
        if (self.state, command) == (S.QUICK_STOP_ACTIVE, DeviceCommand.ENABLE_OPERATION):
            if self.quick_stop_option in RESUMABLE_QUICK_STOP and not self.quick_stop_input_active:
                self.state = S.OPERATION_ENABLED  # 16
            return False
        self.state = TRANSITIONS.get((self.state, command), self.state)
        return False

    def apply(self, command: DeviceCommand) -> None:
        """A device-control command from the drive itself: the same transitions as the
        master's, without touching the controlword history (a fault reset stays an edge)."""
        if self.state is not S.FAULT:
            self.state = TRANSITIONS.get((self.state, command), self.state)

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

    def statusword_bits(self) -> int:
        return STATE_STATUS[self.state]

