"""The monitor's loop: every check period, read the heartbeat and the device, judge, and stop.

One check: take every heartbeat datagram waiting; read the device through the monitor's own
connection; compare joints, speeds and the wrist force with the limits (kernel/safety/checks.py)
and, with a ``[geometry]`` table, the arm's place against its solids (kernel/safety/space.py);
add a lost heartbeat, motion while no warden run heartbeats, and a device that stopped
answering. A breach that was not there at the previous check stops the arm at once, through the
watch's own stop path, and is logged with what was seen. A breach that persists while the arm
still moves is stopped again every ``restop_interval_ms``. Nothing is latched beyond that: a
joint left outside its limit keeps ``warden safety status`` from answering ok until someone
brings it back.

Stop bound, from the moment a breach exists on the device to the stop reaching it:
one check period (the breach happens just after a check) + the check's own read + the stop
path's latency; for a lost heartbeat, ``heartbeat_timeout_ms`` + one check period from the last
heartbeat warden sent. Then the arm's stopping time. docs/operations.md, "Safety monitor", gives
the figures measured.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import structlog

from kernel.safety.checks import Breach, Finding, Limits, Sample, breaches
from kernel.safety.heartbeat import HeartbeatReceiver, Pulse
from kernel.safety.settings import SafetySettings
from kernel.safety.watch import DeviceLost, DeviceWatch, StopResult

if TYPE_CHECKING:
    from kernel.safety.space import SpaceCheck

log = structlog.get_logger("warden.safety")


class Stopping(Protocol):
    """What ends :meth:`Monitor.run`: the service's :class:`~kernel.safety.service.SignalledStop`,
    or a ``threading.Event`` another thread sets."""

    def is_set(self) -> bool: ...

    def wait(self, timeout: float) -> bool: ...


PROBE_EVERY_NS = 1_000_000_000
RECONNECT_EVERY_NS = 1_000_000_000
WATCHING_SLACK_NS = 50_000_000
"""A loop whose last check is older than three periods plus this is not watching."""
LIMIT_BREACHES = frozenset({Breach.POSITION, Breach.VELOCITY, Breach.FORCE, Breach.SPACE})


@dataclass(frozen=True, slots=True)
class StopRecord:
    at_ns: int
    findings: tuple[str, ...]
    result: StopResult
    took_ms: float
    repeated: bool


class Monitor:
    def __init__(self, settings: SafetySettings, limits: Limits, watch: DeviceWatch,
                 heartbeat: HeartbeatReceiver,
                 clock: Callable[[], int] = time.monotonic_ns,
                 space: SpaceCheck | None = None) -> None:
        self.settings, self.limits, self.watch, self.heartbeat = settings, limits, watch, heartbeat
        self.space = space
        """The measured arm against ``[geometry]``'s solids, on every sample; None: the
        manifest has no solid the monitor checks."""
        self.clock = clock
        self.lock = threading.Lock()
        """Held while a check updates what :meth:`status` reads."""
        self.checks = 0
        self.stops: list[StopRecord] = []
        self.stop_count = 0
        self._period_ns = round(settings.check_period_ms * 1e6)
        self._moving = settings.moving_rad_s
        self._last_check_ns: int | None = None
        self._sample: Sample | None = None
        self._findings: list[Finding] = []
        self._device_problem: str | None = None
        self._blind_since_ns: int | None = None
        self._blind_problem: str | None = None
        self._stopped_session: int | None = None
        """The warden run (heartbeat session) in which the monitor last stopped the device."""
        self._stop_path_problem: str | None = None
        self._next_probe_ns = self._next_reconnect_ns = 0
        self._judge_motion_from_ns = clock() + settings.heartbeat_timeout_ns
        """A monitor (re)started while warden runs has not had its heartbeat yet: motion
        without one is judged only once a heartbeat would have arrived."""

    # -- the loop -----------------------------------------------------------------------------

    def run(self, stopping: Stopping, after_check: Callable[[], Any] | None = None) -> None:
        """Check every period until ``stopping`` is set; a late check is never caught up."""
        deadline = self.clock()
        while not stopping.is_set():
            self.check()
            if after_check is not None:
                after_check()
            deadline += self._period_ns
            delay = deadline - self.clock()
            if delay > 0:
                stopping.wait(delay / 1e9)
            else:
                deadline = self.clock()

    def check(self) -> None:
        now = self.clock()
        self.heartbeat.drain(now)
        sample, lost = self._read(now)
        if lost and self.watch.lives_in_warden and self.heartbeat.state(now) is Pulse.NONE:
            lost = None  # no warden run, so no simulated world: nothing there can move
        lost = lost or self._blind(sample, now)
        findings = [lost] if lost else []
        if sample is not None:
            findings += breaches(sample, self.limits)
            if self.space is not None:
                findings += self.space.findings(sample.q)
        findings += self._heartbeat_findings(sample, now)
        with self.lock:
            previous = {f.breach for f in self._findings}
            self._sample, self._findings = sample, findings
            self._last_check_ns = self.clock()
            self.checks += 1
        self._act(findings, previous, sample, now)
        if not findings and now >= self._next_probe_ns:
            self._next_probe_ns = now + PROBE_EVERY_NS
            self._probe()

    def _read(self, now: int) -> tuple[Sample | None, Finding | None]:
        if self._device_problem is not None and now >= self._next_reconnect_ns:
            self._next_reconnect_ns = now + RECONNECT_EVERY_NS
            if self.watch.reconnect():
                log.info("device connection back", device=self.watch.description)
                self._device_problem = None
        if self._device_problem is not None:
            return None, Finding(Breach.DEVICE_LOST, self._device_problem)
        try:
            return self.watch.sample(), None
        except DeviceLost as error:
            self._device_problem = str(error)
            self._next_reconnect_ns = now + RECONNECT_EVERY_NS
            return None, Finding(Breach.DEVICE_LOST, str(error))

    def _blind(self, sample: Sample | None, now: int) -> Finding | None:
        """A watch with its own connection that reads nothing while warden runs is as good as
        lost (a CiA 402 listener on the wrong bus hears nothing, and silence alone is idle
        drives to it); after the monitor's own stop in this run, quiet is what it asked for."""
        current = self.heartbeat.current
        if sample is not None or not self.watch.can_stop or current is None or (
                self.heartbeat.state(now) is not Pulse.ALIVE
                or self._stopped_session == current.session):
            self._blind_since_ns = self._blind_problem = None
            return None
        if self._blind_since_ns is None:
            self._blind_since_ns = now
        blind_ms = (now - self._blind_since_ns) / 1e6
        if blind_ms <= self.settings.device_timeout_ms:
            return None
        self._blind_problem = (
            f"warden (pid {current.pid}) runs but the device gave the monitor nothing to read "
            f"for {blind_ms:.0f} ms (device_timeout_ms {self.settings.device_timeout_ms:g}): "
            "check that the manifest names the device warden drives")
        return Finding(Breach.DEVICE_LOST, self._blind_problem)

    def _heartbeat_findings(self, sample: Sample | None, now: int) -> list[Finding]:
        pulse = self.heartbeat.state(now)
        current = self.heartbeat.current
        if pulse is Pulse.LOST and current is not None and current.closing_ns is not None:
            return [Finding(Breach.HEARTBEAT_LOST, f"warden (pid {current.pid}) said its loop "
                            "ended but did not finish closing within "
                            f"{self.settings.closing_timeout_ms:g} ms")]
        if pulse is Pulse.LOST and current is not None:
            return [Finding(Breach.HEARTBEAT_LOST, f"no heartbeat from warden (pid "
                            f"{current.pid}) for {self.heartbeat.age_ms(now):.0f} ms (timeout "
                            f"{self.settings.heartbeat_timeout_ms:g} ms)")]
        if pulse is Pulse.NONE and sample is not None and sample.fastest > self._moving and (
                now >= self._judge_motion_from_ns):
            return [Finding(Breach.MOTION_WITHOUT_WARDEN,
                            f"a joint moves at {sample.fastest:.3f} rad/s and no warden run is "
                            "heartbeating")]
        return []

    # -- stopping -----------------------------------------------------------------------------

    def _act(self, findings: list[Finding], previous: set[Breach], sample: Sample | None,
             now: int) -> None:
        kinds = {f.breach for f in findings}
        if kinds - previous:
            self._stop(findings, now, repeated=False)
        elif kinds and self.watch.can_stop and self._still_moving(sample) and (
                self._restop_due(now)):
            self._stop(findings, now, repeated=True)
        elif previous and not kinds:
            log.info("safety breach cleared", was=sorted(previous))

    def _still_moving(self, sample: Sample | None) -> bool:
        if sample is None:
            # A device the monitor lost may be moving unseen; one that is not lost and gives
            # nothing to read (CiA 402 drives out of OPERATIONAL) takes no setpoint.
            return self._device_problem is not None or self._blind_problem is not None
        return sample.fastest > self._moving

    def _restop_due(self, now: int) -> bool:
        last = self.stops[-1].at_ns if self.stops else None
        interval = round(self.settings.restop_interval_ms * 1e6)
        return last is None or now - last >= interval

    def _stop(self, findings: list[Finding], now: int, repeated: bool) -> None:
        started = time.perf_counter()
        result = self.watch.stop()
        current = self.heartbeat.current
        self._stopped_session = None if current is None else current.session
        took = (time.perf_counter() - started) * 1e3
        record = StopRecord(now, tuple(map(str, findings)), result, round(took, 3), repeated)
        quiet = repeated and not result.done and bool(self.stops) and not (
            self.stops[-1].result.done)  # the same failure again: counted, not logged again
        with self.lock:
            self.stops.append(record)
            del self.stops[:-20]  # the recent ones are what status shows
            self.stop_count += 1
        if quiet:
            return
        fields = {"violations": list(record.findings), "stop_path": self.watch.stop_path,
                  "answer": result.detail, "stop_ms": record.took_ms, "repeated": repeated}
        if result.done:
            log.error("safety stop", **fields)
        else:
            log.critical("safety stop failed", **fields)

    def _probe(self) -> None:
        problem = self.watch.probe()
        if problem != self._stop_path_problem:
            if problem:
                log.error("stop path does not answer", stop_path=self.watch.stop_path,
                          detail=problem)
            else:
                log.info("stop path answers", stop_path=self.watch.stop_path)
        with self.lock:
            self._stop_path_problem = problem

    # -- what `warden safety status` shows ----------------------------------------------------

    def status(self) -> dict[str, Any]:
        now = self.clock()
        with self.lock:
            last, sample, findings = self._last_check_ns, self._sample, list(self._findings)
            problem = self._device_problem or self._blind_problem or self._stop_path_problem
            stop = self.stops[-1] if self.stops else None
            checks, count = self.checks, self.stop_count
        watching = last is not None and now - last <= 3 * self._period_ns + WATCHING_SLACK_NS
        connected = problem is None
        problems = [str(f) for f in findings if f.breach in LIMIT_BREACHES]
        if not watching:
            problems.append("the monitor's loop has not completed a check recently")
        if not connected:
            problems.append(str(problem))
        pulse = self.heartbeat.state(now)
        return {
            "ok": watching and connected and not problems, "problems": problems,
            "watching": watching, "connected": connected, "checks": checks,
            "last_check_ms": None if last is None else round((now - last) / 1e6, 3),
            "device": self.watch.description, "stop_path": self.watch.stop_path,
            "can_stop": self.watch.can_stop,
            "heartbeat": {"state": str(pulse), "age_ms": _rounded(self.heartbeat.age_ms(now)),
                          "pid": self.heartbeat.current.pid if self.heartbeat.current else None,
                          "timeout_ms": self.settings.heartbeat_timeout_ms},
            "breaches": [str(f) for f in findings],
            "stops": count, "last_stop": _stop_summary(stop, now),
            "fastest_rad_s": _rounded(sample.fastest if sample else None),
            "force_n": _rounded(sample.force_n if sample else None),
            "space": None if self.space is None else list(self.space.solids),
        }


def _rounded(value: float | None) -> float | None:
    return None if value is None else round(value, 3)


def _stop_summary(stop: StopRecord | None, now: int) -> dict[str, Any] | None:
    if stop is None:
        return None
    return {"ago_ms": round((now - stop.at_ns) / 1e6, 1), "violations": list(stop.findings),
            "done": stop.result.done, "answer": stop.result.detail, "took_ms": stop.took_ms}
