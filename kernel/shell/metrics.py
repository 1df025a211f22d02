"""Live metrics: what a run has decided so far, in shared memory, for a Prometheus endpoint
served by a process of its own (``kernel/shell/metrics_exporter.py``).

A scrape must never delay a tick. An HTTP server inside warden's process would run Python on
warden's interpreter lock for every scrape, right beside the control loop. So the run only
writes numbers into a block of shared memory, a fixed layout of float64 slots
(:class:`MetricsLayout`), every ``publish_interval_ms`` from what the run summary has already
counted (a few hundred slot writes, nothing per tick); the exporter, a child process with its
own interpreter, reads the block when it is scraped and formats it. Labels are bounded by
construction: task phases, reason codes, decisions and fallback modes, never an id. A scrape
is not synchronised with a publish: it may read a histogram's sum and count from either side
of one (counters only ever grow, so no series goes backwards).

The endpoint's socket is bound by warden before the run opens anything, so a port that is
taken is an invalid manifest (exit 2, naming ``metrics.port``); the child inherits it.
"""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from multiprocessing import resource_tracker, shared_memory

import numpy as np

from assurance.fallback import Mode
from assurance.reasons import ReasonCode
from kernel.core.lines import Decision
from kernel.shell.link_types import LinkCounters
from kernel.shell.realtime import children_at_ordinary_priority
from kernel.summary import RunSummary
from skills.phases import TaskPhase

AGE_BUCKETS_MS = (2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0)
LATENCY_BUCKETS_MS = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0)
"""A fallback transition, from its trigger to the first tick that commands the new mode."""
PROJECTION_BUCKETS_RAD = (1e-5, 1e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1)
LINK_COUNTERS = tuple(f.name for f in fields(LinkCounters))


@dataclass(frozen=True, slots=True)
class Histogram:
    buckets: tuple[float, ...]
    at: int
    """Its first slot: one per bucket (non-cumulative), one for +Inf, then the sum."""

    @property
    def width(self) -> int:
        return len(self.buckets) + 2


@dataclass(frozen=True, slots=True)
class MetricsLayout:
    """Where each number lives in the block: the same on both sides of it."""

    slots: dict[str, int]
    """Each metric's first slot."""
    size: int
    phases: tuple[str, ...] = tuple(TaskPhase)
    reasons: tuple[str, ...] = tuple(ReasonCode)
    decisions: tuple[str, ...] = tuple(Decision)
    modes: tuple[str, ...] = tuple(Mode)
    links: tuple[str, ...] = LINK_COUNTERS

    @classmethod
    def build(cls) -> MetricsLayout:
        phases, reasons, modes = len(TaskPhase), len(ReasonCode), len(Mode)
        widths = (("ticks", 1), ("requests", 1), ("queue_depth", 1), ("journal_gaps", 1),
                  ("deadline_misses", 1), ("published", 1), ("proposals", phases),
                  ("decisions", len(Decision)), ("refusals", phases * reasons),
                  ("transitions", modes ** 2), ("triggers", reasons),
                  ("links", len(LINK_COUNTERS)),
                  ("action_age", len(AGE_BUCKETS_MS) + 2),
                  ("projection", len(PROJECTION_BUCKETS_RAD) + 2),
                  ("latency", modes * (len(LATENCY_BUCKETS_MS) + 2)))  # a histogram per mode
        slots, at = {}, 0
        for name, width in widths:
            slots[name] = at
            at += width
        return cls(slots=slots, size=at)

    def histogram(self, name: str) -> Histogram:
        buckets = AGE_BUCKETS_MS if name == "action_age" else PROJECTION_BUCKETS_RAD
        return Histogram(buckets, self.slots[name])

    def latency(self, to_mode: str) -> Histogram | None:
        """The transition-latency histogram of the mode a transition went to."""
        if to_mode not in self.modes:
            return None
        width = len(LATENCY_BUCKETS_MS) + 2
        return Histogram(LATENCY_BUCKETS_MS,
                         self.slots["latency"] + self.modes.index(to_mode) * width)

    def trigger(self, reason: str) -> int | None:
        return self.slots["triggers"] + self.reasons.index(reason) if (
            reason in self.reasons) else None

    def refusal(self, phase: str, reason: str) -> int | None:
        if phase not in self.phases or reason not in self.reasons:
            return None
        return (self.slots["refusals"] + self.phases.index(phase) * len(self.reasons)
                + self.reasons.index(reason))

    def transition(self, from_mode: str, to_mode: str) -> int | None:
        if from_mode not in self.modes or to_mode not in self.modes:
            return None
        return (self.slots["transitions"] + self.modes.index(from_mode) * len(self.modes)
                + self.modes.index(to_mode))


LAYOUT = MetricsLayout.build()


class MetricsBlock:
    """The shared block, created by the run (``name`` None) or attached by the exporter."""

    def __init__(self, name: str | None = None) -> None:
        size = LAYOUT.size * 8
        self.memory = (shared_memory.SharedMemory(create=True, size=size) if name is None
                       else shared_memory.SharedMemory(name=name))
        self.owner = name is None
        if not self.owner:  # Python 3.11 would unlink the run's block when the reader exits
            resource_tracker.unregister(self.memory._name, "shared_memory")  # type: ignore
        self.values: np.ndarray = np.ndarray((LAYOUT.size,), dtype="<f8",
                                             buffer=self.memory.buf)
        if self.owner:
            self.values[:] = 0.0

    @property
    def name(self) -> str:
        return self.memory.name

    def close(self) -> None:
        del self.values  # the view must go before the buffer can be released
        try:
            self.memory.close()
        finally:
            if self.owner:
                self.memory.unlink()


class MetricsPublisher:
    """Writes what the run summary has counted into the block; each list the summary keeps
    (action ages, projection distances, transitions) is read from where the last publish
    stopped, so a publish costs what happened since the last one."""

    def __init__(self, block: MetricsBlock) -> None:
        self.block = block
        self._seen = {"action_age": 0, "projection": 0, "transitions": 0, "latency": 0}

    def publish(self, summary: RunSummary, links: Mapping[str, int],
                loop: Mapping[str, int]) -> None:
        """``loop``: the run's own counts, ``journal_gaps`` and ``deadline_misses``."""
        values, slots = self.block.values, LAYOUT.slots
        values[slots["ticks"]] = summary.ticks
        values[slots["requests"]] = summary.requests
        if summary.queue_depth:
            values[slots["queue_depth"]] = summary.queue_depth[-1]
        for name in ("journal_gaps", "deadline_misses"):
            values[slots[name]] = loop.get(name, 0)
        for index, phase in enumerate(LAYOUT.phases):
            values[slots["proposals"] + index] = summary.proposals.get(phase, 0)
        for index, decision in enumerate(LAYOUT.decisions):
            values[slots["decisions"] + index] = summary.decisions.get(decision, 0)
        for phase, reasons in summary.refusals.items():
            for reason, count in reasons.items():
                slot = LAYOUT.refusal(phase, reason)
                if slot is not None:
                    values[slot] = count
        for index, name in enumerate(LAYOUT.links):
            values[slots["links"] + index] = links.get(name, 0)
        self._transitions(summary.transitions)
        self._observe("action_age", summary.action_age_ms)
        self._observe("projection", summary.projection)
        values[slots["published"]] += 1

    def _transitions(self, transitions: list[dict[str, object]]) -> None:
        values = self.block.values
        for record in transitions[self._seen["transitions"]:]:
            for slot in (LAYOUT.transition(str(record["from"]), str(record["to"])),
                         LAYOUT.trigger(str(record["trigger"]))):
                if slot is not None:
                    values[slot] += 1
        self._seen["transitions"] = len(transitions)
        # A transition's latency is known once a tick commands its mode: count those in order,
        # stopping at the first still waiting (the run's summary fills it in later).
        for record in transitions[self._seen["latency"]:]:
            latency = record.get("latency_ms")
            if latency is None:
                break
            histogram = LAYOUT.latency(str(record["to"]))
            if histogram is not None:
                at = histogram.at + int(np.searchsorted(histogram.buckets, float(latency)))
                values[at] += 1
                values[histogram.at + histogram.width - 1] += float(latency)
            self._seen["latency"] += 1

    def _observe(self, name: str, observed: list[float]) -> None:
        """Bucket what is new, in one vectorised pass (a publish every 5 s at 500 Hz reads
        2,500 ages)."""
        histogram = LAYOUT.histogram(name)
        new = np.asarray(observed[self._seen[name]:], dtype=float)
        self._seen[name] = len(observed)
        if new.size == 0:
            return
        slots = np.searchsorted(histogram.buckets, new, side="left")  # le: inclusive
        counts = np.bincount(slots, minlength=len(histogram.buckets) + 1)
        values = self.block.values
        values[histogram.at:histogram.at + counts.size] += counts
        values[histogram.at + histogram.width - 1] += float(new.sum())

    async def run(self, started: Callable[[], None], summary: RunSummary,
                  links: Callable[[], Mapping[str, int]],
                  loop: Callable[[], Mapping[str, int]], interval_s: float) -> None:
        """Publish every ``interval_s`` until cancelled (a supervised task of the run)."""
        started()
        while True:
            self.publish(summary, links(), loop())
            await asyncio.sleep(interval_s)


class MetricsUnavailable(Exception):
    """The endpoint cannot be set up; ``key`` is the manifest key to name."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(message)
        self.key = key


class MetricsEndpoint:
    """The endpoint of one run: its bound socket, its block and the exporter serving both."""

    def __init__(self, host: str, port: int) -> None:
        """Raises:
            MetricsUnavailable: the address cannot be bound (a port that is taken), or there is
                no shared memory for the block."""
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.socket = socket.socket(family, socket.SOCK_STREAM)
        try:
            self.socket.bind((host, port))
            self.socket.listen(16)
        except OSError as error:
            self.socket.close()
            raise MetricsUnavailable("port", f"cannot listen on {host}:{port}: "
                                             f"{error.strerror}") from None
        self.port = int(self.socket.getsockname()[1])
        try:
            self.block = MetricsBlock()
        except OSError as error:
            self.socket.close()
            raise MetricsUnavailable("", f"no shared memory for the metrics (/dev/shm): "
                                         f"{error.strerror}") from None
        self.publisher = MetricsPublisher(self.block)
        self._child: subprocess.Popen[bytes] | None = None
        self.exit_code: int | None = None
        """The exporter's exit status once the run closed it (None: never started)."""

    def start(self) -> None:
        """The exporter, given the socket and the block; it exits when its stdin closes (this
        process ending, cleanly or not, closes it)."""
        with children_at_ordinary_priority():  # at SCHED_FIFO its imports took the loop's CPU
            self._child = subprocess.Popen(
                [sys.executable, "-m", "kernel.shell.metrics_exporter", "--block",
                 self.block.name, "--fd", str(self.socket.fileno())],
                stdin=subprocess.PIPE, pass_fds=(self.socket.fileno(),))
        self.socket.close()  # the exporter's now: were it to die, scrapes are refused, not held

    @property
    def pid(self) -> int | None:
        return None if self._child is None else self._child.pid

    def close(self) -> None:
        try:
            if self._child is not None:
                if self._child.stdin is not None:
                    self._child.stdin.close()
                try:
                    self.exit_code = self._child.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    self._child.kill()
                    self.exit_code = self._child.wait()
        finally:
            self.socket.close()
            self.block.close()

