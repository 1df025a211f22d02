"""An injectable reading glitch: one joint's reported position is off, the plant is not.

A real encoder, its cable or the device's firmware can report a joint somewhere it is not for
a few samples (an EMI burst, a torn frame, a multi-turn counter that slips). The emulators
report what this says and move the plant as they always do: the arm stays where physics puts
it, only the reading lies. A glitch lasts ``duration_ms`` of wall time from its injection, or
the next ``samples`` samples the device reports (one RTDE frame, one bus read, one SYNC).

Control port: ``{"fault": "reading_glitch", "joint": 0, "offset": 0.5, "duration_ms": 200}``
(or ``"samples": 1`` instead of the duration); ``clear`` ends it. Test tooling only.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence
from typing import Any


class ReadingGlitch:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._joint = 0
        self._offset = 0.0
        self._until: float | None = None
        self._samples = 0
        self.reported = 0
        """Samples reported with the offset so far (tests read it)."""

    def start(self, request: dict[str, Any]) -> dict[str, Any]:
        """The control port's ``reading_glitch``."""
        joint, offset = int(request["joint"]), float(request["offset"])
        if joint < 0 or not math.isfinite(offset):
            raise ValueError(f"joint {joint} and offset {offset} must be a joint and a number")
        samples = int(request.get("samples", 0))
        duration_ms = float(request.get("duration_ms", 0.0))
        if (samples > 0) == (duration_ms > 0):
            raise ValueError("give either samples or duration_ms, positive")
        with self._lock:
            self._joint, self._offset, self._samples = joint, offset, samples
            self._until = time.monotonic() + duration_ms * 1e-3 if duration_ms > 0 else None
            self.reported = 0
        return {"started": time.monotonic()}

    def clear(self) -> None:
        with self._lock:
            self._samples, self._until = 0, None

    def offset(self, joint: int, now: float | None = None) -> float:
        """The offset of ``joint`` in the sample taken now (counts the sample: call once per
        sample, for the glitched joint's reading)."""
        with self._lock:
            if joint != self._joint or not self._active(now):
                return 0.0
            if self._samples > 0:
                self._samples -= 1
            self.reported += 1
            return self._offset

    def apply(self, q: Sequence[float], now: float | None = None) -> tuple[float, ...]:
        """The joints as one sample reports them."""
        reported = list(q)
        if 0 <= self._joint < len(reported):
            reported[self._joint] += self.offset(self._joint, now)
        return tuple(reported)

    def _active(self, now: float | None) -> bool:
        if self._samples > 0:
            return True
        if self._until is None:
            return False
        return (time.monotonic() if now is None else now) < self._until
