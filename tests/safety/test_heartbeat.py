"""warden's heartbeat and the monitor's receiver, over a real Unix datagram socket.

Time is the receiver's argument (``now_ns``), so the states are judged at chosen instants; the
datagrams, the kernel's credentials and the file permissions are real.
"""

from __future__ import annotations

import os
import socket
import stat
import time
from pathlib import Path

import pytest

from kernel.safety.heartbeat import HeartbeatReceiver, Pulse
from kernel.shell.heartbeat import WIRE, Beat, BeatKind, HeartbeatSender

TIMEOUT_NS = 200_000_000
CLOSING_NS = 2_000_000_000


@pytest.fixture
def receiver(tmp_path: Path):  # type: ignore[no-untyped-def]
    made = HeartbeatReceiver(tmp_path / "hb.sock", os.getegid(), TIMEOUT_NS, CLOSING_NS)
    yield made
    made.close()


def _raw(path: Path, beat: Beat | bytes) -> None:
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.sendto(beat if isinstance(beat, bytes) else beat.pack(), str(path))


def test_every_nth_tick_beats_and_the_first_at_once(receiver: HeartbeatReceiver) -> None:
    sender = HeartbeatSender(receiver.path, every_ticks=5)
    sent = [sender.beat() for _ in range(11)]
    assert sent == [True, False, False, False, False, True, False, False, False, False, True]
    receiver.drain(time.monotonic_ns())
    assert receiver.current is not None and receiver.current.pid == os.getpid()
    # Judged at the last beat's own stamp: a test process paused for longer than the timeout
    # between the beat and the drain (a loaded host) would otherwise read LOST.
    assert receiver.state(receiver.current.last_ns) is Pulse.ALIVE
    assert receiver.counters.received == 3 and sender.stats.sent == 3


def test_silence_longer_than_the_timeout_is_lost(receiver: HeartbeatReceiver) -> None:
    HeartbeatSender(receiver.path).beat()
    now = time.monotonic_ns()
    receiver.drain(now)
    sent_at = receiver.current.last_ns  # type: ignore[union-attr]
    assert receiver.state(sent_at + TIMEOUT_NS) is Pulse.ALIVE
    assert receiver.state(sent_at + TIMEOUT_NS + 1) is Pulse.LOST


def test_a_datagram_that_waited_in_the_queue_is_judged_by_its_stamp(
        receiver: HeartbeatReceiver) -> None:
    old = time.monotonic_ns() - TIMEOUT_NS - 50_000_000
    _raw(receiver.path, Beat(BeatKind.BEAT, os.getpid(), 7, 0, old))
    now = time.monotonic_ns()
    receiver.drain(now)
    assert receiver.state(now) is Pulse.LOST  # received now, but sent too long ago


def test_closing_then_end_is_an_orderly_end(receiver: HeartbeatReceiver) -> None:
    sender = HeartbeatSender(receiver.path)
    sender.beat()
    sender.closing()
    assert not sender.beat()  # no heartbeat after CLOSING
    now = time.monotonic_ns()
    receiver.drain(now)
    assert receiver.state(now + TIMEOUT_NS * 5) is Pulse.CLOSING  # closing may take a while
    assert receiver.state(now + CLOSING_NS + 1) is Pulse.LOST  # but not for ever
    sender.close()
    receiver.drain(time.monotonic_ns())
    assert receiver.state(time.monotonic_ns()) is Pulse.NONE and receiver.current is None


def test_a_payload_naming_another_pid_is_refused(receiver: HeartbeatReceiver) -> None:
    _raw(receiver.path, Beat(BeatKind.BEAT, os.getpid() + 1, 7, 0, time.monotonic_ns()))
    receiver.drain(time.monotonic_ns())
    assert receiver.current is None and receiver.counters.refused == 1


@pytest.mark.parametrize("payload", [
    b"hello", WIRE.pack(b"XXXX", 1, os.getpid(), 1, 0, 0),
    WIRE.pack(b"WDHB", 9, os.getpid(), 1, 0, 0),
])
def test_malformed_datagrams_are_refused(receiver: HeartbeatReceiver, payload: bytes) -> None:
    _raw(receiver.path, payload)
    receiver.drain(time.monotonic_ns())
    assert receiver.current is None and receiver.counters.refused == 1


def test_a_stamp_from_the_future_is_refused(receiver: HeartbeatReceiver) -> None:
    _raw(receiver.path, Beat(BeatKind.BEAT, os.getpid(), 7, 0, time.monotonic_ns() + 10**9))
    receiver.drain(time.monotonic_ns())
    assert receiver.current is None and receiver.counters.refused == 1


def test_old_and_repeated_sequence_numbers_change_nothing(receiver: HeartbeatReceiver) -> None:
    now = time.monotonic_ns()
    for seq, stamp in ((5, now), (5, now + 1), (3, now + 2)):
        _raw(receiver.path, Beat(BeatKind.BEAT, os.getpid(), 7, seq, stamp))
    receiver.drain(now + 3)
    assert receiver.current is not None and receiver.current.last_ns == now


def test_a_second_run_is_taken_up_only_once_the_first_is_lost(
        receiver: HeartbeatReceiver) -> None:
    now = time.monotonic_ns()
    _raw(receiver.path, Beat(BeatKind.BEAT, os.getpid(), 1, 0, now))
    _raw(receiver.path, Beat(BeatKind.BEAT, os.getpid(), 2, 0, now))
    receiver.drain(now)
    assert receiver.current.session == 1 and receiver.counters.refused == 1  # type: ignore
    later = now + TIMEOUT_NS + 1
    _raw(receiver.path, Beat(BeatKind.BEAT, os.getpid(), 2, 1, later - 1))
    receiver.drain(later)
    assert receiver.current.session == 2  # type: ignore[union-attr]


def test_the_socket_belongs_to_the_group_only(receiver: HeartbeatReceiver) -> None:
    mode = receiver.path.stat().st_mode
    assert stat.S_ISSOCK(mode) and stat.S_IMODE(mode) == 0o660
    assert receiver.path.stat().st_gid == os.getegid()


def test_a_stale_socket_is_replaced_and_a_live_one_is_not(tmp_path: Path) -> None:
    path = tmp_path / "hb.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as dead:
        dead.bind(str(path))
    first = HeartbeatReceiver(path, os.getegid(), TIMEOUT_NS, CLOSING_NS)  # took the stale one
    try:
        with pytest.raises(OSError, match="another safety monitor receives on this socket"):
            HeartbeatReceiver(path, os.getegid(), TIMEOUT_NS, CLOSING_NS)
    finally:
        first.close()
    assert not path.exists()


def test_a_sender_with_no_monitor_counts_failures_and_never_raises(tmp_path: Path) -> None:
    sender = HeartbeatSender(tmp_path / "nobody.sock", every_ticks=1)
    assert [sender.beat() for _ in range(3)] == [False, False, False]
    assert (sender.stats.sent, sender.stats.failed, sender.stats.last_error) == (0, 3, "ENOENT")
    sender.close()


def test_a_disabled_sender_does_nothing() -> None:
    sender = HeartbeatSender(None)
    assert not sender.enabled and not sender.beat()
    sender.closing()
    sender.close()
    assert sender.summary() == {"socket": "-", "sent": 0, "failed": 0, "last_error": None}
