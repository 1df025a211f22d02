"""The seams between chunks with and without real-time chunking, in one run.

A real core (the wire tests' loopback gateway, tests/wire/harness.py) and warden's real client
talk to the reference policy server (in process, over loopback websockets) that moves the arm
toward a goal with the shipped cell's policy model:
0.25 rad/s, 3 rad/s² ramps, 0.5 mrad of noise, 20-action chunks every 20 ms, 30 ms median and
60 ms p95 inference. The arm follows every setpoint exactly (2 ms ticks). The same run is made
twice, the server offering real-time chunking or not (docs/protocol.md, "Real-time chunking").

At each admission the committed actions one, two and three steps ahead are read from the
core (``Core.committed``) just before and just after: the *seam step* is the largest change
of any joint among them (what the new chunk changed of the motion already under way). The
*seam jerk* is the third difference of the action stream across the seam (the actions in force
one step before and at the admission, as the ticks recorded them, then one and two steps
ahead after it), in rad/s³.
Figures are printed, never asserted; compare the two rows of one run.

    .venv/bin/python bench/rtc_seams.py [--seconds 4]
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from collections import Counter, deque
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make the repository importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from assurance.envelope import Chunk
from kernel.core.effects import Step
from kernel.core.events import ChunkEvent, Event
from kernel.core.lines import ChunkLine
from kernel.shell.client import RobotClient
from kernel.shell.link_settings import PolicySettings
from kernel.shell.link_types import ClientConfig
from kernel.summary import ADMITTED
from stubs.policy_server import LatencyModel, PolicyServer, ServerConfig
from tests.wire.harness import LoopbackGateway
from tools.scenarios.base import Q0

DT_NS = 20_000_000
GOAL = tuple(q + d for q, d in zip(Q0, (0.6, -0.5, 0.5, -0.4, 0.3, 0.6), strict=True))
TICK_S = 0.002


class _SeamGateway(LoopbackGateway):
    """The wire tests' gateway (a real core, an arm that follows every command); each chunk's
    admission is measured against what was committed before it."""

    def __init__(self) -> None:
        super().__init__("FREE_SPACE", {"request_retry_ms": 250})  # the shipped cell's
        self.steps: list[float] = []
        self.jerks: list[float] = []
        self.admitted = self.refused = self.conditioned = 0
        self.history: deque[tuple[int, np.ndarray]] = deque(maxlen=200)
        self.reasons: Counter[str] = Counter()

    def feed(self, event: Event) -> Step:
        chunk = event.chunk if isinstance(event, ChunkEvent) else None
        before = self._ahead(event.t) if isinstance(chunk, Chunk) else None
        step = super().feed(event)
        if before is not None and isinstance(chunk, Chunk):
            self._measure(event.t, chunk, before, step)
        return step

    def tick(self) -> None:
        super().tick()
        now = self.now_ns()
        value = self._value(now)
        if value is not None:
            self.history.append((now, value))

    def _value(self, t: int) -> np.ndarray | None:
        """The committed action in force at ``t`` (now or later), or None."""
        committed = self.core.committed(t, DT_NS)
        return None if committed is None or not len(committed.rows) else committed.rows[0]

    def _past(self, t: int) -> np.ndarray | None:
        """The action that was in force at ``t`` (the ticks' record: the queue forgets)."""
        earlier = [value for when, value in self.history if when <= t]
        return earlier[-1] if earlier else None

    def _ahead(self, t: int) -> list[np.ndarray | None]:
        return [self._value(t + k * DT_NS) for k in range(1, 4)]

    def _measure(self, t: int, chunk: Chunk, before: list[np.ndarray | None],
                 step: Step) -> None:
        admitted = any(isinstance(line, ChunkLine) and line.decision in ADMITTED
                       for line in step.lines)
        self.admitted += admitted
        self.refused += not admitted
        for line in step.lines:
            if isinstance(line, ChunkLine) and not admitted:
                self.reasons.update(map(str, line.reasons))
        self.conditioned += admitted and chunk.rtc_delay is not None
        after = self._ahead(t)
        past = [self._past(t - DT_NS), self._value(t)]
        points = [*before, *after, *past]
        if not admitted or any(value is None for value in points):
            return  # the first chunk, or a queue that ran dry: no seam to speak of
        self.steps.append(max(float(np.abs(a - b).max()) for a, b in zip(after, before,
                                                                          strict=True)))
        stream = np.vstack((*past, *after[:2]))
        jerk = np.abs(np.diff(stream, n=3, axis=0)).max() / (DT_NS * 1e-9) ** 3
        self.jerks.append(float(jerk))


async def _run(rtc: bool, seconds: float) -> _SeamGateway:
    server = ServerConfig(rtc=rtc, goal=GOAL, max_speed=0.25, max_acceleration=3.0,
                          noise_std=5e-4, horizon=20, action_dt_ms=DT_NS / 1e6,
                          latency=LatencyModel(30.0, 60.0), replacement_policy="blend")
    gateway = _SeamGateway()
    link = PolicySettings(heartbeat_interval_ms=100.0, heartbeat_timeout_ms=2000.0)
    async with PolicyServer(server) as policy:
        client = RobotClient(ClientConfig(url=f"ws://127.0.0.1:{policy.port}",
                                          client_id="seams", policy=link), gateway)
        stop = asyncio.Event()
        async with asyncio.TaskGroup() as tasks:
            tasks.create_task(client.run())
            tasks.create_task(gateway.run_ticks(stop, period_s=TICK_S))
            await asyncio.sleep(seconds)
            stop.set()
            client.stop()
    return gateway


def _row(name: str, g: _SeamGateway) -> str:
    def pct(values: list[float], p: float) -> float:
        return float(np.percentile(values, p)) if values else float("nan")
    return (f"{name:<9} admitted {g.admitted:4d} (conditioned {g.conditioned:4d}, refused "
            f"{g.refused:3d})  seam step p50 {pct(g.steps, 50) * 1e3:7.3f} p95 "
            f"{pct(g.steps, 95) * 1e3:7.3f} mrad   seam jerk p50 {pct(g.jerks, 50):8.2f} "
            f"p95 {pct(g.jerks, 95):8.2f} rad/s³  ({len(g.steps)} seams)\n"
            f"{'':<9} refused for: {dict(g.reasons) or 'nothing'}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=4.0)
    args = parser.parse_args(argv)
    without = asyncio.run(_run(False, args.seconds))
    with_rtc = asyncio.run(_run(True, args.seconds))
    print(_row("without", without))
    print(_row("with RTC", with_rtc))
    ratio = np.median(with_rtc.steps) / np.median(without.steps) if without.steps else np.nan
    print(f"seam step p50, with / without: {ratio:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
