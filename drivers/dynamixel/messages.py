"""Wording of the driver's errors: each names the port, the servo ids and what to check.

Pure functions, so the bus code stays about the bus and the wording can be read in one place.
"""

from __future__ import annotations

from collections.abc import Iterable

from drivers.dynamixel.tables import hardware_error_names


def ids_text(ids: Iterable[int]) -> str:
    return ", ".join(str(i) for i in ids)


def missing_servos(port: str, baud: int, missing: Iterable[int], found: Iterable[int]) -> str:
    where = f"on {port} at {baud} baud"
    found = list(found)
    if not found:
        return (f"no servo answers {where} (tried ids {ids_text(missing)}); check that `baud` "
                "matches the servos' Baud Rate (address 8), that the bus has power, and the cable")
    return (f"servo id {ids_text(missing)} does not answer {where} (ids {ids_text(found)} do); "
            "check `ids`, that servo's power and the daisy-chain cable to it")


def link_lost(port: str, attempts: int, last: str, silent: list[int], garbled: list[int]) -> str:
    failed = f"{attempts} sync reads failed, last: {last}"
    if silent:
        return (f"servo id {ids_text(silent)} on {port} stopped answering ({failed}); check its "
                "power and the daisy-chain cable")
    if garbled:
        return (f"servo id {ids_text(garbled)} on {port} answer with corrupt packets ({failed}); "
                "check the cable, termination and for a second master on the bus")
    return (f"sync read on {port} failed {attempts} times in a row ({last}) although every servo "
            "answers ping; check for bus noise")


def hardware_error(port: str, statuses: dict[int, int | None]) -> str:
    """``statuses``: Hardware Error Status per alerting servo, None where it was unreadable."""
    parts = []
    for dxl_id, status in statuses.items():
        if status is None:
            parts.append(f"servo id {dxl_id}: alert bit set, Hardware Error Status unreadable")
        else:
            names = ", ".join(hardware_error_names(status)) or "no bit set"
            parts.append(f"servo id {dxl_id}: {names} (Hardware Error Status 0x{status:02x})")
    return (f"hardware error on {port}: {'; '.join(parts)}; the servo switches its torque off: "
            "remove the cause, then reboot or power-cycle it")
