"""The monitor's decisions: when it stops, when it stops again, what it reports.

The device is a scripted stand-in for a watch (the monitor's own interface, not a vendor
library); the heartbeat goes over the real socket; time is a clock the test moves.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from kernel.safety.checks import Limits, Sample
from kernel.safety.devices import HeartbeatOnly
from kernel.safety.heartbeat import HeartbeatReceiver
from kernel.safety.monitor import Monitor
from kernel.safety.settings import SafetySettings
from kernel.safety.watch import DeviceLost, StopResult
from kernel.shell.heartbeat import Beat, BeatKind

MS = 1_000_000
SETTINGS = SafetySettings(max_wrist_force_n=50.0)
LIMITS = Limits(lower=(-1.0,), upper=(1.0,), velocity=(1.0,), max_force_n=50.0,
                position_margin=0.0, velocity_margin=0.0)
AT_REST = Sample(q=(0.0,), qd=(0.0,), force_n=0.0)


class ScriptedWatch:
    """A device whose next reading the test sets; it records every stop."""

    description, stop_path = "scripted arm", "scripted stop"
    can_stop = True

    def __init__(self, lives_in_warden: bool = False) -> None:
        self.lives_in_warden = lives_in_warden
        self.reading: Sample | DeviceLost = AT_REST
        self.stops = 0
        self.reconnects = 0

    def connect(self) -> None: ...

    def sample(self) -> Sample:
        if isinstance(self.reading, DeviceLost):
            raise self.reading
        return self.reading

    def stop(self) -> StopResult:
        self.stops += 1
        return StopResult(True, "stopped")

    def probe(self) -> str | None:
        return None

    def reconnect(self) -> bool:
        self.reconnects += 1
        return not isinstance(self.reading, DeviceLost)

    def close(self) -> None: ...


class Clock:
    def __init__(self) -> None:
        self.ns = 10**12

    def __call__(self) -> int:
        return self.ns

    def advance(self, ms: float) -> None:
        self.ns += round(ms * MS)


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def receiver(tmp_path: Path):  # type: ignore[no-untyped-def]
    made = HeartbeatReceiver(tmp_path / "hb.sock", os.getegid(), SETTINGS.heartbeat_timeout_ns,
                             SETTINGS.closing_timeout_ns)
    yield made
    made.close()


def _monitor(watch, receiver, clock) -> Monitor:  # type: ignore[no-untyped-def]
    return Monitor(SETTINGS, LIMITS, watch, receiver, clock)


def _beat(receiver: HeartbeatReceiver, clock: Clock, seq: int,
          kind: BeatKind = BeatKind.BEAT) -> None:
    import socket

    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.sendto(Beat(kind, os.getpid(), 42, seq, clock.ns).pack(), str(receiver.path))


def test_a_new_breach_stops_once_and_a_still_arm_is_not_stopped_again(
        receiver: HeartbeatReceiver, clock: Clock) -> None:
    watch = ScriptedWatch()
    monitor = _monitor(watch, receiver, clock)
    monitor.check()
    assert watch.stops == 0 and monitor.status()["ok"]
    watch.reading = Sample(q=(1.2,), qd=(0.0,), force_n=0.0)  # came to rest past its limit
    monitor.check()
    assert watch.stops == 1
    for _ in range(300):
        clock.advance(4)
        monitor.check()
    assert watch.stops == 1
    status = monitor.status()
    assert not status["ok"] and status["problems"] == [
        "position: joint 0 at 1.2000 rad, limits [-1, 1]"]
    assert status["last_stop"]["violations"] == status["problems"]


def test_a_breach_that_persists_while_the_arm_moves_is_stopped_again(
        receiver: HeartbeatReceiver, clock: Clock) -> None:
    watch = ScriptedWatch()
    monitor = _monitor(watch, receiver, clock)
    watch.reading = Sample(q=(1.2,), qd=(0.5,), force_n=0.0)
    _beat(receiver, clock, 0)  # warden alive all along: the only breach is the position
    monitor.check()
    clock.advance(SETTINGS.restop_interval_ms - 1)
    _beat(receiver, clock, 1)
    monitor.check()
    assert watch.stops == 1
    clock.advance(1)
    monitor.check()
    assert watch.stops == 2


def test_a_lost_heartbeat_stops_the_arm(receiver: HeartbeatReceiver, clock: Clock) -> None:
    watch = ScriptedWatch()
    monitor = _monitor(watch, receiver, clock)
    _beat(receiver, clock, 0)
    for _ in range(round(SETTINGS.heartbeat_timeout_ms / 4)):
        monitor.check()
        clock.advance(4)
    assert watch.stops == 0 and monitor.status()["heartbeat"]["state"] == "alive"
    clock.advance(4)
    monitor.check()
    assert watch.stops == 1
    assert monitor.status()["last_stop"]["violations"][0].startswith(
        f"heartbeat_lost: no heartbeat from warden (pid {os.getpid()}) for 204 ms")
    assert monitor.status()["ok"]  # alive, connected, watching: a lost warden is not its fault


def test_an_orderly_end_is_not_a_loss_but_motion_after_it_is(
        receiver: HeartbeatReceiver, clock: Clock) -> None:
    watch = ScriptedWatch()
    monitor = _monitor(watch, receiver, clock)
    _beat(receiver, clock, 0)
    monitor.check()
    _beat(receiver, clock, 1, BeatKind.CLOSING)
    watch.reading = Sample(q=(0.1,), qd=(0.3,), force_n=0.0)  # warden brings the arm to rest
    for _ in range(100):
        clock.advance(10)
        monitor.check()
    assert watch.stops == 0 and monitor.status()["heartbeat"]["state"] == "closing"
    _beat(receiver, clock, 2, BeatKind.END)
    monitor.check()  # nobody drives the arm now, and it still moves
    assert watch.stops == 1
    assert monitor.status()["last_stop"]["violations"] == [
        "motion_without_warden: a joint moves at 0.300 rad/s and no warden run is heartbeating"]


def test_a_monitor_started_mid_motion_waits_one_timeout_for_wardens_heartbeat(
        receiver: HeartbeatReceiver, clock: Clock) -> None:
    watch = ScriptedWatch()
    watch.reading = Sample(q=(0.1,), qd=(0.3,), force_n=0.0)
    monitor = _monitor(watch, receiver, clock)  # (re)started while warden moves the arm
    monitor.check()
    clock.advance(SETTINGS.heartbeat_timeout_ms - 10)
    _beat(receiver, clock, 0)
    monitor.check()
    clock.advance(100)
    monitor.check()
    assert watch.stops == 0 and monitor.status()["heartbeat"]["state"] == "alive"


def test_motion_with_no_warden_at_all_is_stopped_after_one_timeout(
        receiver: HeartbeatReceiver, clock: Clock) -> None:
    watch = ScriptedWatch()
    watch.reading = Sample(q=(0.1,), qd=(0.3,), force_n=0.0)
    monitor = _monitor(watch, receiver, clock)
    monitor.check()
    clock.advance(SETTINGS.heartbeat_timeout_ms)
    monitor.check()
    assert watch.stops == 1


def test_a_run_that_never_finishes_closing_is_lost(receiver: HeartbeatReceiver,
                                                   clock: Clock) -> None:
    watch = ScriptedWatch()
    monitor = _monitor(watch, receiver, clock)
    _beat(receiver, clock, 0)
    _beat(receiver, clock, 1, BeatKind.CLOSING)
    monitor.check()
    clock.advance(SETTINGS.closing_timeout_ms + 1)
    monitor.check()
    assert watch.stops == 1
    assert "did not finish closing within 10000 ms" in monitor.status()["last_stop"][
        "violations"][0]


def test_a_lost_device_is_a_breach_and_is_reconnected(receiver: HeartbeatReceiver,
                                                      clock: Clock) -> None:
    watch = ScriptedWatch()
    monitor = _monitor(watch, receiver, clock)
    watch.reading = DeviceLost("no new data for 300 ms")
    monitor.check()
    assert watch.stops == 1 and not monitor.status()["connected"]
    watch.reading = AT_REST
    clock.advance(1000)
    monitor.check()
    assert watch.reconnects == 1 and monitor.status()["connected"]


def test_a_world_inside_warden_is_not_lost_when_no_warden_runs(
        receiver: HeartbeatReceiver, clock: Clock) -> None:
    watch = ScriptedWatch(lives_in_warden=True)
    monitor = _monitor(watch, receiver, clock)
    watch.reading = DeviceLost("the simulated world does not answer")
    monitor.check()
    assert watch.stops == 0 and not monitor.status()["connected"]


def test_a_monitor_that_cannot_stop_says_so_and_does_not_retry(
        receiver: HeartbeatReceiver, clock: Clock) -> None:
    watch = HeartbeatOnly("a bus", "the servos' Bus Watchdog")
    monitor = _monitor(watch, receiver, clock)
    _beat(receiver, clock, 0)
    monitor.check()
    for _ in range(400):
        clock.advance(4)
        monitor.check()
    assert monitor.stop_count == 1
    status = monitor.status()
    assert not status["can_stop"] and status["last_stop"]["done"] is False
    assert "this monitor cannot stop the arm" in status["last_stop"]["answer"]


def test_a_loop_that_stopped_checking_is_not_watching(receiver: HeartbeatReceiver,
                                                      clock: Clock) -> None:
    monitor = _monitor(ScriptedWatch(), receiver, clock)
    assert not monitor.status()["watching"]  # no check yet
    monitor.check()
    assert monitor.status()["ok"]
    clock.advance(100)
    status = monitor.status()
    assert not status["ok"] and not status["watching"]
    assert "the monitor's loop has not completed a check recently" in status["problems"]


def test_a_device_that_gives_nothing_to_read_while_warden_runs_is_lost(
        receiver: HeartbeatReceiver, clock: Clock) -> None:
    watch = ScriptedWatch()
    watch.reading = None  # type: ignore[assignment]  # a CiA 402 listener on the wrong bus
    monitor = _monitor(watch, receiver, clock)
    monitor.check()
    assert watch.stops == 0 and monitor.status()["ok"]  # idle drives, no warden: nothing to read
    for tick in range(round(SETTINGS.device_timeout_ms / 4)):
        if tick % 10 == 0:
            _beat(receiver, clock, tick)
        monitor.check()
        clock.advance(4)
    assert watch.stops == 0
    clock.advance(4)
    monitor.check()
    assert watch.stops == 1
    status = monitor.status()
    assert not status["ok"] and not status["connected"]
    assert status["last_stop"]["violations"][0].startswith(
        f"device_lost: warden (pid {os.getpid()}) runs but the device gave the monitor nothing "
        "to read for 252 ms")


def test_quiet_after_the_monitors_own_stop_in_that_run_is_not_a_loss(
        receiver: HeartbeatReceiver, clock: Clock) -> None:
    watch = ScriptedWatch()
    monitor = _monitor(watch, receiver, clock)
    _beat(receiver, clock, 0)
    watch.reading = Sample(q=(1.2,), qd=(0.5,), force_n=0.0)
    monitor.check()
    assert watch.stops == 1
    watch.reading = None  # type: ignore[assignment]  # stopped drives send no process data
    for tick in range(500):
        if tick % 10 == 0:
            _beat(receiver, clock, tick + 1)  # warden runs on until its driver notices
        clock.advance(4)
        monitor.check()
    assert watch.stops == 1 and monitor.status()["ok"]


def test_nothing_to_read_is_not_stopped_again_but_a_lost_device_is(
        receiver: HeartbeatReceiver, clock: Clock) -> None:
    watch = ScriptedWatch()
    monitor = _monitor(watch, receiver, clock)
    _beat(receiver, clock, 0)
    monitor.check()
    watch.reading = None  # type: ignore[assignment]  # drives that take no setpoint
    clock.advance(SETTINGS.heartbeat_timeout_ms + 4)  # and warden hangs
    for _ in range(500):
        monitor.check()
        clock.advance(4)
    assert watch.stops == 1
    watch.reading = DeviceLost("no TPDO for 300 ms")  # now the device may move unseen
    for _ in range(round(SETTINGS.restop_interval_ms / 4) + 1):
        monitor.check()
        clock.advance(4)
    assert watch.stops == 3  # the new breach at once, then again one interval later
