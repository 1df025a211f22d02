"""A real core behind a real client, talking to the reference server over loopback.

:class:`LoopbackGateway` is the gateway a test shell provides: a :class:`kernel.core.runtime.Core`
built from the standard cell of ``tools/scenarios/base.py`` (no session until a handshake, as
in a live run), an arm that follows every command exactly, and a control tick loop; the core's
effects (inference requests, the end of a session) reach the client through the handlers it
registers, as in a live run. Nothing of the core is mocked.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np

from assurance.handshake import ClientHello
from kernel.config.build import build_config
from kernel.core.effects import Hold, Step, Stop
from kernel.core.events import Event, LinkEvent, StateEvent, TickEvent
from kernel.core.lines import ChunkLine, HandshakeLine, Line, TickLine
from kernel.core.runtime import Core
from kernel.journal import event_record
from kernel.scenario.events import parse_events
from kernel.scenario.fields import Where
from kernel.shell.client import RobotClient
from kernel.shell.link_budget import AdmissionPacer
from kernel.shell.link_settings import PolicySettings
from kernel.shell.link_types import CameraFrames, ClientConfig, RobotSample
from kernel.summary import ADMITTED
from stubs.policy_server import LatencyModel, PolicyServer, ServerConfig
from tools.scenarios.base import ScenarioSpec, session

TIMING = {"low_watermark_ms": 150, "high_watermark_ms": 400, "request_retry_ms": 40}
CLOCK_OFFSET_NS = 1_234_567_891  # the server's clock runs this far ahead of ours


class LoopbackGateway:
    def __init__(self, phase: str = "FREE_SPACE", timing: dict[str, Any] | None = None,
                 protocol: tuple[int, int] = (1, 2),
                 cameras: list[dict[str, Any]] | None = None) -> None:
        spec = ScenarioSpec(name="wire", description="", events=[], until=0, expect=[],
                            phase=phase, timing={**TIMING, **(timing or {})},
                            session={**session(phase), "protocol": list(protocol)},
                            cameras=cameras)
        config = build_config(spec.document(), Where("wire", ""))
        self.config = dataclasses.replace(config, initial_session=None)
        self.core = Core(self.config)
        self.q = self.config.initial_q.copy()
        self.events: list[Event] = []
        self.lines: list[Line] = []
        self.client: RobotClient | None = None
        self.handlers: dict[type, list[Callable[[Any], None]]] = {}
        self.origin_ns = time.monotonic_ns()

    # -- the Gateway protocol ------------------------------------------------------------------

    def now_ns(self) -> int:
        return time.monotonic_ns() - self.origin_ns

    def feed(self, event: Event) -> Step:
        self.events.append(event)
        step = self.core.step(event)
        self.lines.extend(step.lines)
        for record in (*step.decisions, *step.effects):
            for handler in self.handlers.get(type(record), ()):
                handler(record)
        return step

    def on(self, kind: type, handler: Callable[[Any], None]) -> None:
        self.handlers.setdefault(kind, []).append(handler)

    def client_side_hello(self) -> ClientHello:
        return self.config.client.hello(self.core.status().epoch)

    def capture_observation(self, prefix_grid_ns: int | None = None,
                            at_ns: int | None = None) -> RobotSample:
        committed = None
        if prefix_grid_ns is not None:  # as kernel/shell/gateway.py does
            at = self.now_ns() if at_ns is None else at_ns
            committed = self.core.committed(at, prefix_grid_ns)
        return RobotSample(q=self.q.copy(), task_phase=str(self.core.status().phase),
                           qd=np.zeros_like(self.q), wrench=np.zeros(6), committed=committed)

    # -- the shell's control loop --------------------------------------------------------------

    def tick(self) -> None:
        motion = self.feed(TickEvent(t=self.now_ns())).motion
        if motion is not None and not isinstance(motion, Hold | Stop):
            self.q = np.array(motion.q, dtype=float)
        self.feed(StateEvent(t=self.now_ns(), q=tuple(self.q)))

    async def run_ticks(self, stop: asyncio.Event, period_s: float = 0.004,
                        pacer: AdmissionPacer | None = None) -> None:
        while not stop.is_set():
            self.tick()
            if pacer is not None:  # as the live control loop does after writing its command
                pacer.period_done(time.monotonic_ns() + round(period_s * 1e9))
            await asyncio.sleep(period_s)

    # -- what happened -------------------------------------------------------------------------

    def chunk_lines(self) -> list[ChunkLine]:
        return [line for line in self.lines if isinstance(line, ChunkLine)]

    def admitted(self) -> list[ChunkLine]:
        return [line for line in self.chunk_lines() if line.decision in ADMITTED]

    def refused_with(self, reason: str) -> list[ChunkLine]:
        return [line for line in self.chunk_lines() if reason in line.reasons]

    def handshakes(self) -> list[HandshakeLine]:
        return [line for line in self.lines if isinstance(line, HandshakeLine)]

    def link_events(self, status: str) -> list[LinkEvent]:
        return [e for e in self.events if isinstance(e, LinkEvent) and e.status == status]


@dataclass
class Link:
    gateway: LoopbackGateway
    client: RobotClient
    server: PolicyServer


_LAST: Link | None = None


def server_config(**changes: Any) -> ServerConfig:
    # A slow arm (0.1 rad/s): a chunk that arrives after one of this VM's pauses (100-200 ms
    # garbage-collector or scheduler stalls were seen) still projects within 0.02 rad of the
    # hold, so a pause costs a stale refusal, never an INFEASIBLE → REPLAN_OR_RETREAT.
    base = ServerConfig(latency=LatencyModel(2.0, 4.0), clock_offset_ns=CLOCK_OFFSET_NS,
                        max_speed=0.1, heartbeat_interval_s=0.05, heartbeat_timeout_s=0.5)
    return dataclasses.replace(base, **changes)


def client_config(port: int, **changes: Any) -> ClientConfig:
    """The test client's configuration; a change named as a ``[policy]`` key (in its unit, ms)
    goes to the link's :class:`PolicySettings`, any other to :class:`ClientConfig`."""
    policy_keys = {f.name for f in msgspec.structs.fields(PolicySettings)}
    policy = PolicySettings(**{"heartbeat_interval_ms": 50.0, "heartbeat_timeout_ms": 500.0,
                               **{k: v for k, v in changes.items() if k in policy_keys}})
    base = ClientConfig(url=f"ws://127.0.0.1:{port}", client_id="robot-test", policy=policy,
                        clock_burst=5, clock_refresh_s=0.5, backoff_initial_s=0.02,
                        backoff_max_s=0.2)
    return dataclasses.replace(base, **{k: v for k, v in changes.items()
                                        if k not in policy_keys})


@contextlib.asynccontextmanager
async def running(
    server: ServerConfig | None = None, gateway: LoopbackGateway | None = None,
    port: int | None = None, pacer: AdmissionPacer | None = None,
    cameras: CameraFrames | None = None, **client_changes: Any,
) -> AsyncIterator[Link]:
    """A server (in-process unless ``port`` names one elsewhere), a client and a tick loop
    (which hands out admission slots when a ``pacer`` is given, as the live loop does)."""
    gateway = gateway or LoopbackGateway()
    async with contextlib.AsyncExitStack() as stack:
        policy = await stack.enter_async_context(PolicyServer(server or server_config()))
        if "url" in client_changes:  # a URL of another scheme: "{port}" is filled in
            client_changes["url"] = client_changes["url"].format(port=port or policy.port)
        client = RobotClient(client_config(port or policy.port, **client_changes), gateway,
                             pacer=pacer, cameras=cameras)
        gateway.client = client
        stop = asyncio.Event()
        async with asyncio.TaskGroup() as tasks:
            tasks.create_task(client.run())
            tasks.create_task(gateway.run_ticks(stop, pacer=pacer))
            global _LAST
            _LAST = Link(gateway, client, policy)
            try:
                yield _LAST
            finally:
                stop.set()
                client.stop()


def journal_round_trip(gateway: LoopbackGateway) -> None:
    """Every event the core was fed becomes a journal line that parses back (the replay's
    first step): a value the journal cannot carry would make the run unreplayable."""
    records = [event_record(event) for event in gateway.events]
    parsed = parse_events(records, Where("journal", "events"), gateway.config.limits)
    assert len(parsed) == len(records)


async def wait_for(condition: Callable[[], object], what: str, timeout_s: float = 8.0) -> None:
    """Wait for ``condition``; the generous timeout only turns a hang into a failure."""
    try:
        async with asyncio.timeout(timeout_s):
            while not condition():
                await asyncio.sleep(0.005)
    except TimeoutError as error:
        raise AssertionError(f"timed out waiting for: {what}\n{_story()}") from error


def _story() -> str:
    """What the last link did, for the failure message."""
    if _LAST is None:
        return ""
    lines = [line for line in _LAST.gateway.lines if not isinstance(line, TickLine)]
    return "\n".join([str(_LAST.client.counters.snapshot()), *map(str, lines[-12:])])
