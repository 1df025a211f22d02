"""Time arithmetic of the chunk contract (docs/contract.md §2, seed §3.1).

All times are integer nanoseconds on the client's monotonic clock unless a name says otherwise.
Scenario files and journals carry milliseconds; the conversion happens at their edge only.

For action ``j`` of chunk ``k`` executed at ``t_exec``::

    age   = t_exec - t_obs(k)
    slack = t_deadline - t_ready

An action is expired when ``age + uncertainty > max_age`` or ``slack < 0``. Both predicates are
monotonic in the clock uncertainty: more uncertainty never makes an expired action valid.
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


def conservative_age(t_exec: int, t_obs: int, uncertainty: int) -> int:
    """The age the client must assume when clocks are known only to within ``uncertainty``."""
    return t_exec - t_obs + max(uncertainty, 0)


def is_expired(
    t_exec: int, t_obs: int, max_age: int, uncertainty: int, t_deadline: int, t_ready: int
) -> bool:
    """docs/contract.md §2: too old (with uncertainty) for its phase, or late for its deadline."""
    too_old = conservative_age(t_exec, t_obs, uncertainty) > max_age
    return too_old or slack(t_deadline, t_ready) < 0


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
