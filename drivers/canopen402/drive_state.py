"""Walk a drive through the CiA 402 power states, never out of FAULT (device thread only).

canopen's ``BaseNode402.state`` setter would do the walk, but its path from FAULT goes through a
fault reset (controlword 0x80): a drive that faults in the middle of an enable would be reset
and enabled again without anyone deciding it. Here each step uses the library's own controlword
setter and ``check_statusword`` (which waits for the next TPDO), and a FAULT ends the walk.
"""

from __future__ import annotations

import time

from assurance.reasons import ReasonCode
from drivers.base import DeviceFault
from drivers.canopen402._sdk import Node402
from drivers.canopen402.settings import CiA402Settings
from drivers.canopen402.tables import Controlword, DriveState, decode_state

FAULTY = frozenset({DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE})

ENABLE_STEPS: dict[DriveState, tuple[Controlword, DriveState]] = {
    DriveState.SWITCH_ON_DISABLED: (Controlword.SHUTDOWN, DriveState.READY_TO_SWITCH_ON),
    DriveState.READY_TO_SWITCH_ON: (Controlword.SWITCH_ON, DriveState.SWITCHED_ON),
    DriveState.SWITCHED_ON: (Controlword.ENABLE_OPERATION, DriveState.OPERATION_ENABLED),
    DriveState.QUICK_STOP_ACTIVE: (Controlword.ENABLE_OPERATION, DriveState.OPERATION_ENABLED),
}
"""From each state, the command that moves one transition closer to OPERATION ENABLED."""


def current_state(node: Node402) -> DriveState:
    return decode_state(node.statusword)


def walk_to(node: Node402, target: DriveState, settings: CiA402Settings) -> None:
    """Bring ``node`` to OPERATION ENABLED or SWITCH ON DISABLED.

    Raises:
        DeviceFault: the drive is or goes into FAULT, or does not follow in time.
    """
    deadline = time.monotonic() + settings.state_timeout_s
    state = current_state(node)
    while state is not target:
        _refuse_fault(node, state, target, settings)
        step = _next_step(state, target)
        if step is not None:
            command, expected = step
            node.controlword = command
            state = _await_state(node, expected, deadline, settings)
        else:  # NOT READY TO SWITCH ON: the drive moves on by itself
            state = _await_state(node, DriveState.SWITCH_ON_DISABLED, deadline, settings)
    node.controlword = _holding_command(target)


def _next_step(state: DriveState, target: DriveState) -> tuple[Controlword, DriveState] | None:
    if state is DriveState.NOT_READY_TO_SWITCH_ON:
        return None
    if target is DriveState.SWITCH_ON_DISABLED:
        return Controlword.DISABLE_VOLTAGE, DriveState.SWITCH_ON_DISABLED
    return ENABLE_STEPS.get(state)


def _holding_command(target: DriveState) -> Controlword:
    """The controlword that keeps the drive in ``target`` on every following cycle."""
    if target is DriveState.OPERATION_ENABLED:
        return Controlword.ENABLE_OPERATION
    return Controlword.DISABLE_VOLTAGE


def _await_state(node: Node402, expected: DriveState, deadline: float,
                 settings: CiA402Settings) -> DriveState:
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            state = current_state(node)
            raise DeviceFault(
                settings.name, f"{settings.node_label(node.id)} did not reach {expected} within "
                f"{settings.state_timeout_s} s: it reports {state} "
                f"(statusword 0x{node.statusword:04X})",
                ReasonCode.CONTROLLER_FAULT,
            )
        try:
            node.check_statusword(timeout=min(remaining, 0.2))
        except RuntimeError:
            continue  # no TPDO this time; the deadline decides
        state = current_state(node)
        if state is expected or state in FAULTY:
            return state


def _refuse_fault(node: Node402, state: DriveState, target: DriveState,
                  settings: CiA402Settings) -> None:
    if state in FAULTY:
        raise DeviceFault(
            settings.name, f"{settings.node_label(node.id)} is in {state} (statusword "
            f"0x{node.statusword:04X}); not moving it to {target}: a fault is reset only at "
            "connect",
            ReasonCode.CONTROLLER_FAULT,
        )
    if state is DriveState.UNKNOWN:
        raise DeviceFault(settings.name, f"{settings.node_label(node.id)} reports an undefined "
                          f"statusword 0x{node.statusword:04X}", ReasonCode.CONTROLLER_FAULT)


def check_running(node: Node402, settings: CiA402Settings, active: bool,
                  stop_requested: bool) -> None:
    """The check every read and write makes of each drive's last statusword.

    Raises:
        DeviceFault: the drive is in FAULT, or left OPERATION ENABLED while the driver is
            active (QUICK STOP ACTIVE is expected only after our own quick stop).
    """
    state = current_state(node)
    if state in FAULTY:
        raise DeviceFault(settings.name, f"{settings.node_label(node.id)} reports {state} "
                          f"(statusword 0x{node.statusword:04X})", ReasonCode.CONTROLLER_FAULT)
    expected = state is DriveState.OPERATION_ENABLED or (
        stop_requested and state is DriveState.QUICK_STOP_ACTIVE)
    if active and not expected:
        cause = " (a quick stop the drive made itself)" if (
            state is DriveState.QUICK_STOP_ACTIVE) else ""
        raise DeviceFault(settings.name, f"{settings.node_label(node.id)} left OPERATION "
                          f"ENABLED: it reports {state}{cause}", ReasonCode.CONTROLLER_FAULT)
