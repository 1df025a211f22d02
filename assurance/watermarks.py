"""Low/high watermarks with hysteresis: when to ask the policy for a new chunk.

Watermarks manage throughput, never safety: they decide when to *request*, not what may run.
Depth is measured in time (how long the queue can still feed the controller), because the low
watermark must cover the inference round trip, which is a time. The effective low watermark
rises with the measured p95 round trip, so a slow server is asked earlier rather than starving
the queue. One request is in flight at a time; a request that gets no answer is repeated after
``retry_ns``.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class WatermarkConfig:
    low_ns: int = 100_000_000
    high_ns: int = 400_000_000
    retry_ns: int = 250_000_000
    margin_ns: int = 10_000_000
    window: int = 64

    def __post_init__(self) -> None:
        if not 0 <= self.low_ns < self.high_ns:
            raise ValueError("watermarks need 0 <= low < high")
        if self.retry_ns <= 0:
            raise ValueError("retry interval must be positive")


class Watermarks:
    def __init__(self, config: WatermarkConfig) -> None:
        self.config = config
        self.requesting = False
        self._in_flight_since: int | None = None
        self._round_trips: deque[int] = deque(maxlen=config.window)

    def record_round_trip(self, ns: int) -> None:
        if ns >= 0:
            self._round_trips.append(ns)

    def p95_round_trip(self) -> int | None:
        if not self._round_trips:
            return None
        ordered = sorted(self._round_trips)
        return ordered[max(0, -(-95 * len(ordered) // 100) - 1)]  # nearest rank

    @property
    def low_ns(self) -> int:
        p95 = self.p95_round_trip()
        adaptive = p95 + self.config.margin_ns if p95 is not None else 0
        return min(max(self.config.low_ns, adaptive), self.config.high_ns - 1)

    def should_request(self, t: int, depth_ns: int, allowed: bool) -> bool:
        """Update the hysteresis state; True when a request should go out at ``t``."""
        if not allowed:
            self.requesting = False
            self._in_flight_since = None
            return False
        if depth_ns >= self.config.high_ns:
            self.requesting = False
        elif depth_ns <= self.low_ns:
            self.requesting = True
        if not self.requesting:
            return False
        since = self._in_flight_since
        if since is not None and t - since < self.config.retry_ns:
            return False
        self._in_flight_since = t
        return True

    def answered(self) -> None:
        """A chunk was admitted: the request in flight has been answered."""
        self._in_flight_since = None
