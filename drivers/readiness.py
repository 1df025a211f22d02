"""What a driver can tell ``warden check`` about its device without moving it.

A driver that overrides ``Driver.inspect`` (:mod:`drivers.base`; :class:`Inspectable` is its
signature) reads its device's own configuration (modes, limits, calibration, power state) and
compares it with the settings and limits it was configured with; each comparison is one
:class:`Finding`. Inspection only reads: no motion command, no parameter write. The kernel
calls it while the driver is ACTIVE (the device holds on its own), after it has watched the
device for a while, and before it deactivates it.
"""

from __future__ import annotations

from collections.abc import Sequence
from enum import StrEnum
from typing import Protocol, runtime_checkable

import msgspec


class CheckVerdict(StrEnum):
    READY = "READY"
    NOT_READY = "NOT READY"
    NOT_EXERCISED = "NOT EXERCISED"
    """A check that a run without motion cannot make; ``reason`` says why."""


class Finding(msgspec.Struct, frozen=True, kw_only=True):
    """One row of the readiness table."""

    name: str
    expected: str
    measured: str
    verdict: CheckVerdict
    reason: str = ""
    """Why it is not ready, or why it was not exercised (empty when ready)."""


@runtime_checkable
class Inspectable(Protocol):
    async def inspect(self) -> tuple[Finding, ...]:
        """Read the device's configuration and compare it with the driver's settings.

        Raises:
            DriverError: the device could not be read.
        """
        ...


def judged(name: str, expected: str, measured: str, problems: Sequence[str]) -> Finding:
    """READY when ``problems`` is empty, else NOT READY with every problem named."""
    if not problems:
        return Finding(name=name, expected=expected, measured=measured, verdict=CheckVerdict.READY)
    return Finding(name=name, expected=expected, measured=measured, verdict=CheckVerdict.NOT_READY,
                   reason="; ".join(problems))


def not_exercised(name: str, expected: str, reason: str, measured: str = "-") -> Finding:
    return Finding(name=name, expected=expected, measured=measured,
                   verdict=CheckVerdict.NOT_EXERCISED, reason=reason)


def span(values: Sequence[float], decimals: int = 3) -> str:
    """``[a, b, c]`` with a fixed number of decimals (table cells stay short)."""
    return "[" + ", ".join(f"{v:.{decimals}f}" for v in values) + "]"
