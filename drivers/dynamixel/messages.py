"""Wording of the driver's errors: each names the port, the servo ids and what to check.

Pure functions, so the bus code stays about the bus and the wording can be read in one place.
"""

from __future__ import annotations

from collections.abc import Iterable

from drivers.dynamixel.tables import hardware_error_names


def ids_text(ids: Iterable[int], gripper_id: int | None = None) -> str:
    """``1, 2, 7 (gripper)``: the gripper is marked, since its id alone says nothing."""
    return ", ".join(f"{i} (gripper)" if i == gripper_id else str(i) for i in ids)


def missing_servos(port: str, baud: int, missing: Iterable[int], found: Iterable[int],
                   gripper_id: int | None = None) -> str:
    where = f"on {port} at {baud} baud"
    missing, found = list(missing), list(found)
    if not found:
        return (f"no servo answers {where} (tried ids {ids_text(missing, gripper_id)}); check "
                "that `baud` matches the servos' Baud Rate (address 8), that the bus has power, "
                "and the cable")
    keys = " or ".join(key for key, hit in (("`ids`", any(i != gripper_id for i in missing)),
                                            ("`gripper_id`", gripper_id in missing)) if hit)
    what = (f"gripper servo id {gripper_id}" if missing == [gripper_id]
            else f"servo id {ids_text(missing, gripper_id)}")
    return (f"{what} does not answer {where} (ids "
            f"{ids_text(found, gripper_id)} do); check {keys}, that servo's power and the "
            "daisy-chain cable to it")


def link_lost(port: str, attempts: int, last: str, silent: list[int], garbled: list[int],
              gripper_id: int | None = None) -> str:
    failed = f"{attempts} sync reads failed, last: {last}"
    if silent:
        return (f"servo id {ids_text(silent, gripper_id)} on {port} stopped answering "
                f"({failed}); check its power and the daisy-chain cable")
    if garbled:
        return (f"servo id {ids_text(garbled, gripper_id)} on {port} answer with corrupt packets "
                f"({failed}); check the cable, termination and for a second master on the bus")
    return (f"sync read on {port} failed {attempts} times in a row ({last}) although every servo "
            "answers ping; check for bus noise")


def hardware_error(port: str, statuses: dict[int, int | None],
                   gripper_id: int | None = None) -> str:
    """``statuses``: Hardware Error Status per alerting servo, None where it was unreadable."""
    parts = []
    for dxl_id, status in statuses.items():
        servo = f"servo id {ids_text([dxl_id], gripper_id)}"
        if status is None:
            parts.append(f"{servo}: alert bit set, Hardware Error Status unreadable")
        else:
            names = ", ".join(hardware_error_names(status)) or "no bit set"
            parts.append(f"{servo}: {names} (Hardware Error Status 0x{status:02x})")
    return (f"hardware error on {port}: {'; '.join(parts)}; the servo switches its torque off: "
            "remove the cause, then reboot or power-cycle it")


def watchdog_expired(port: str, stopped: Iterable[int], watchdog_s: float,
                     gripper_id: int | None = None) -> str:
    return (f"servo id {ids_text(stopped, gripper_id)} on {port} stopped: Bus Watchdog expired "
            f"(no instruction packet for more than {watchdog_s * 1e3:.0f} ms while torque was "
            "on: warden stalled or the bus went quiet); they refuse new goals until the driver "
            "is brought up again, which clears it")


def watchdog_unsupported(port: str, dxl_id: int, error: str,
                         gripper_id: int | None = None) -> str:
    return (f"servo id {ids_text([dxl_id], gripper_id)} on {port} refused its Bus Watchdog "
            f"(address 98): {error}; it needs firmware v38 or later (update it with Dynamixel "
            "Wizard), or set watchdog_periods = 0 to run without a device-side watchdog")
