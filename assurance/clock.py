"""Time arithmetic of the chunk contract (docs/contract.md §2).

All times are integer nanoseconds on the client's monotonic clock unless a name says otherwise.
Scenario files and journals carry milliseconds; the conversion happens at their edge only.

For action ``j`` of chunk ``k`` executed at ``t_exec``::

    age   = t_exec - t_obs(k)
    slack = t_deadline - t_ready

An action is expired when ``age + uncertainty > max_age`` or ``slack < 0``. This module is the
one place that turns that into arithmetic, in the form the runtime needs: an action's life ends
at an instant (:func:`expires_at`), computed once per chunk at admission; a row is too old at
``t`` when ``t`` has reached that instant (:func:`too_old`); and the rows of a chunk's grid due
before an instant are counted by :func:`rows_due_before`, which gives both the late prefix
(negative slack: due before ``t_ready``) and the rows that are still young at their own due
time. More uncertainty never makes an expired action valid; a negative uncertainty counts as
none.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

NS_PER_MS = 1_000_000
CLIENT_DOMAIN = "client"


def ms_to_ns(ms: float) -> int:
    """Milliseconds (possibly fractional) to integer nanoseconds, rounded to the nearest."""
    return round(ms * NS_PER_MS)


def ns_to_ms(ns: int) -> int | float:
    """Nanoseconds to milliseconds: an int when whole, so logs stay short and exact."""
    whole, rest = divmod(ns, NS_PER_MS)
    return whole if rest == 0 else ns / NS_PER_MS


def age(t_exec: int, t_obs: int) -> int:
    return t_exec - t_obs


def slack(t_deadline: int, t_ready: int) -> int:
    return t_deadline - t_ready


def expires_at(t_obs: int, max_age: int, uncertainty: int) -> int:
    """The first instant at which an action conditioned on an observation sensed at ``t_obs``
    is too old to run: ``age + uncertainty > max_age`` ⇔ ``t ≥ t_obs + max_age − uncertainty
    + 1`` (integer nanoseconds). At ``age + uncertainty == max_age`` it may still run."""
    return t_obs + max_age - max(uncertainty, 0) + 1


def too_old(t: int, expiry: int) -> bool:
    """Has ``t`` reached the instant ``expiry`` (from :func:`expires_at`)?"""
    return t >= expiry


def rows_due_before(first_due: int, dt: int, instant: int, rows: int) -> int:
    """How many of ``rows`` actions due at ``first_due + j·dt`` are due strictly before
    ``instant``: with ``instant = t_ready``, the late prefix (negative slack); with
    ``instant = expires_at``, the actions still young enough at their own due time."""
    return min(rows, max(0, -(-(instant - first_due) // dt)))


@dataclass(frozen=True, slots=True)
class ClockSync:
    """A measured relation between a foreign clock and the client's monotonic clock.

    ``t_client = t_foreign + offset_ns``, known to within half the measured round trip.
    """

    domain: str
    offset_ns: int
    round_trip_ns: int

    @property
    def uncertainty_ns(self) -> int:
        return (self.round_trip_ns + 1) // 2


_CLIENT_SYNC = ClockSync(CLIENT_DOMAIN, 0, 0)


class ClockInvalid(Exception):
    """A time in a foreign clock domain that has no measured offset and round-trip bound."""


@dataclass(frozen=True, slots=True)
class ClockMap:
    """Which clock domains the client can translate, and with how much uncertainty."""

    base_uncertainty_ns: int = 0
    syncs: tuple[ClockSync, ...] = ()

    def with_sync(self, sync: ClockSync) -> ClockMap:
        others = tuple(s for s in self.syncs if s.domain != sync.domain)
        return ClockMap(self.base_uncertainty_ns, (*others, sync))

    def lookup(self, domain: str) -> ClockSync | None:
        if domain == CLIENT_DOMAIN:
            return _CLIENT_SYNC
        for sync in self.syncs:
            if sync.domain == domain:
                return sync
        return None

    def translator(self, domain: str) -> tuple[int, int]:
        """(offset, total uncertainty) for ``domain``; raises ClockInvalid if unknown.

        Comparing raw wall clocks of two machines is an error, never a guess.
        """
        sync = self.lookup(domain)
        if sync is None:
            raise ClockInvalid(domain)
        return sync.offset_ns, self.base_uncertainty_ns + sync.uncertainty_ns


def finite_ms(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
