"""What every device watch is, and what it may raise: the leaf the watches and the monitor share.

:mod:`kernel.safety.devices` picks a watch for the manifest's driver and imports each kind of
watch (:mod:`kernel.safety.ur`, :mod:`kernel.safety.sim`, :mod:`kernel.safety.canopen`) only
for its own cell; the watches and :mod:`kernel.safety.monitor` import these types from here, so
no module of the monitor imports one that imports it back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from kernel.safety.checks import Sample


class DeviceUnreachable(Exception):
    """The monitor cannot watch this device (at start: exit 2); the message says what to
    check."""


class DeviceLost(Exception):
    """The monitor's view of the device went stale or stopped answering (a breach)."""


@dataclass(frozen=True, slots=True)
class StopResult:
    done: bool
    detail: str
    """The device's answer, or why the stop could not be delivered."""


class DeviceWatch(Protocol):
    description: str
    """The device and the monitor's connection to it, for logs and status."""
    stop_path: str
    """How this monitor stops the arm, or why it cannot."""
    can_stop: bool
    lives_in_warden: bool
    """The device exists only inside warden's process (the simulated world): with no warden
    run it is gone, and nothing can move."""

    def connect(self) -> None:
        """Open the connection and check the stop path answers.

        Raises:
            DeviceUnreachable: either cannot be reached; nothing was commanded.
        """
        ...

    def sample(self) -> Sample | None:
        """The newest reading; None: nothing to read now (a watch that reads no device, or CiA
        402 drives that exchange no process data). A watch that can stop must read while warden
        runs: the monitor counts None for longer than ``device_timeout_ms`` while warden's
        heartbeat is alive as the device lost, unless it stopped the device in that run.

        Raises:
            DeviceLost: no fresh data within ``device_timeout_ms``, or the link is down.
        """
        ...

    def stop(self) -> StopResult:
        """Stop the arm through the monitor's own path; never raises."""
        ...

    def probe(self) -> str | None:
        """Check that the stop path still answers (called about once a second while nothing
        is wrong); the problem, or None. May reconnect."""
        ...

    def reconnect(self) -> bool:
        """After a :class:`DeviceLost`: try once, with a short deadline; True if back."""
        ...

    def close(self) -> None: ...
