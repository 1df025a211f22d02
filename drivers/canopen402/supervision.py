"""What every call of the CiA 402 driver checks: the drives' reports since the last call, and
the errors of a blocking step named after the step."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import can
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from drivers.base import DriverError, DriverInitError, DriverIOError, DriverTimeout
from drivers.canopen402.cycle import BusCycle
from drivers.canopen402.drive_state import check_running
from drivers.canopen402.health import HealthMonitor
from drivers.canopen402.link import Link
from drivers.canopen402.settings import CiA402Settings


def check_drives(health: HealthMonitor, link: Link, cycle: BusCycle | None,
                 settings: CiA402Settings, active: bool, stop_requested: bool) -> None:
    """Raise what the drives reported since the last call (EMCY, silence, state)."""
    try:
        health.check(expect_pdos=cycle is not None)
    except (DriverIOError, DriverTimeout):
        if not link.catch_up():  # silence is only silence once what arrived has been read
            raise
        health.check(expect_pdos=cycle is not None)
    if cycle is None:
        return
    if cycle.error is not None:
        raise DriverIOError(settings.name, f"the bus cycle could not send on "
                            f"{settings.describe_bus()}: {cycle.error}")
    for node in link.nodes:
        check_running(node, settings, active, stop_requested)


@contextlib.contextmanager
def named_step(device: str, label: str) -> Iterator[None]:
    """Turn what canopen and python-can raise in a blocking step into the driver's errors,
    naming the step."""
    try:
        yield
    except DriverError:
        raise
    except (SdoCommunicationError, SdoAbortedError) as error:
        raise DriverInitError(device, f"{label}: SDO failed: {error}") from error
    except can.CanError as error:
        raise DriverIOError(device, f"{label}: {error}") from error
