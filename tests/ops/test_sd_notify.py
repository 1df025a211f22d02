"""sd_notify against real AF_UNIX datagram sockets: what systemd would receive, byte for byte."""

from __future__ import annotations

import itertools
import os
import shutil
import socket
import subprocess
import sys
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from kernel.shell.systemd import (
    STATUS_MAX_CHARS,
    ServiceNotifier,
    message,
    notify,
    notify_address,
    watchdog_interval_s,
)

ROOT = Path(__file__).resolve().parents[2]


class Receiver:
    """A bound datagram socket standing in for systemd's notify socket."""

    def __init__(self, address: str | bytes) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(address)
        self.sock.settimeout(2.0)

    def recv(self) -> bytes:
        return self.sock.recv(4096)

    def pending(self) -> list[bytes]:
        self.sock.setblocking(False)
        found = []
        try:
            while True:
                found.append(self.sock.recv(4096))
        except BlockingIOError:
            return found
        finally:
            self.sock.settimeout(2.0)


@pytest.fixture
def fs_socket(tmp_path: Path) -> Iterator[tuple[dict[str, str], Receiver]]:
    path = str(tmp_path / "notify.sock")
    receiver = Receiver(path)
    yield {"NOTIFY_SOCKET": path}, receiver
    receiver.sock.close()


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_unset_socket_is_a_silent_no_op() -> None:
    assert notify_address({}) is None
    assert notify({}, READY=1) is False
    notifier = ServiceNotifier.from_env({"WATCHDOG_USEC": "2000000"})
    assert not notifier.enabled and notifier.watchdog_s is None
    assert not notifier.ready("up") and not notifier.alive() and not notifier.stopping()
    assert notifier.stats.sent == notifier.stats.failed == 0


def test_addresses() -> None:
    assert notify_address({"NOTIFY_SOCKET": "/run/systemd/notify"}) == "/run/systemd/notify"
    assert notify_address({"NOTIFY_SOCKET": "@abc"}) == b"\0abc"
    assert notify_address({"NOTIFY_SOCKET": "@"}) is None
    assert notify_address({"NOTIFY_SOCKET": "vsock:2:1234"}) is None
    assert notify_address({"NOTIFY_SOCKET": "relative/path"}) is None


def test_message_format_and_sanitizing() -> None:
    assert message(READY=1, STATUS="holding") == b"READY=1\nSTATUS=holding"
    assert message(WATCHDOG=True) == b"WATCHDOG=1"
    # A newline in a value must not smuggle in a second field.
    assert message(STATUS="a\nREADY=1") == b"STATUS=a READY=1"
    with pytest.raises(ValueError, match="upper-case"):
        message(ready=1)


def test_notify_to_a_filesystem_socket(fs_socket: tuple[dict[str, str], Receiver]) -> None:
    env, receiver = fs_socket
    assert notify(env, READY=1, STATUS="driver holding") is True
    assert receiver.recv() == b"READY=1\nSTATUS=driver holding"


def test_notify_to_an_abstract_socket() -> None:
    name = f"warden-test-{uuid.uuid4().hex}"
    receiver = Receiver(b"\0" + name.encode())
    try:
        assert notify({"NOTIFY_SOCKET": f"@{name}"}, WATCHDOG_USEC=3_000_000) is True
        assert receiver.recv() == b"WATCHDOG_USEC=3000000"
        notifier = ServiceNotifier.from_env({"NOTIFY_SOCKET": f"@{name}"})
        assert notifier.status("cycle 2/3")
        assert receiver.recv() == b"STATUS=cycle 2/3"
        notifier.close()
    finally:
        receiver.sock.close()


def test_service_notifier_lifecycle(fs_socket: tuple[dict[str, str], Receiver]) -> None:
    env, receiver = fs_socket
    with ServiceNotifier.from_env(env) as notifier:
        assert notifier.ready("driver holding, 500 Hz")
        assert notifier.status("x" * 500)
        assert notifier.stopping("shutting down")
        assert not notifier.alive()  # no watchdog configured: nothing to ping
    received = [receiver.recv() for _ in range(3)]
    assert received[0] == b"READY=1\nSTATUS=driver holding, 500 Hz"
    assert len(received[1].decode()) == len("STATUS=") + STATUS_MAX_CHARS
    assert received[2] == b"STOPPING=1\nSTATUS=shutting down"
    assert notifier.stats.sent == 3 and notifier.stats.failed == 0


def test_watchdog_interval_from_the_environment() -> None:
    me = os.getpid()
    assert watchdog_interval_s({}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "2000000"}) == 2.0
    assert watchdog_interval_s({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(me)}) == 2.0
    # Inherited by a child: the watchdog is someone else's.
    assert watchdog_interval_s({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(me + 1)}) is None
    for bad in ("0", "", "-5", "2s", "1e6"):
        assert watchdog_interval_s({"WATCHDOG_USEC": bad}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "1", "WATCHDOG_PID": "x"}) is None


def test_alive_is_rate_limited_to_half_the_watchdog(
        fs_socket: tuple[dict[str, str], Receiver]) -> None:
    env, receiver = fs_socket
    clock = FakeClock()
    notifier = ServiceNotifier.from_env({**env, "WATCHDOG_USEC": "2000000"}, clock=clock)
    assert notifier.watchdog_s == 2.0
    sent_at = []
    for tick in range(1500):  # 3 s of a 500 Hz loop
        clock.now = 100.0 + tick * 0.002
        if notifier.alive():
            sent_at.append(tick)
    # One ping per second: the first tick at least 1 s (500 ticks) after the previous ping.
    assert sent_at[0] == 0 and len(sent_at) == 3
    assert all(500 <= later - earlier <= 501 for earlier, later in itertools.pairwise(sent_at))
    assert receiver.pending() == [b"WATCHDOG=1"] * 3
    notifier.close()


def test_a_stuck_loop_stops_the_pings(fs_socket: tuple[dict[str, str], Receiver]) -> None:
    env, receiver = fs_socket
    clock = FakeClock()
    notifier = ServiceNotifier.from_env({**env, "WATCHDOG_USEC": "2000000"}, clock=clock)
    assert notifier.alive()
    clock.now += 5.0  # no alive() calls for 5 s: nothing is sent on the loop's behalf
    assert receiver.pending() == [b"WATCHDOG=1"]
    assert notifier.alive()  # the first healthy tick afterwards pings at once
    notifier.close()


def test_send_errors_are_counted_not_raised(tmp_path: Path) -> None:
    gone = {"NOTIFY_SOCKET": str(tmp_path / "missing.sock"), "WATCHDOG_USEC": "1000"}
    clock = FakeClock()
    notifier = ServiceNotifier.from_env(gone, clock=clock)
    assert notifier.ready("up") is False
    assert notifier.alive() is False
    assert notifier.stats.failed == 2 and notifier.stats.last_error in ("ENOENT", "ECONNREFUSED")
    assert notify(gone, READY=1) is False
    notifier.close()


def test_a_full_socket_never_blocks(fs_socket: tuple[dict[str, str], Receiver]) -> None:
    env, receiver = fs_socket
    notifier = ServiceNotifier.from_env(env)

    def flood() -> None:
        for index in range(5000):  # nobody reads: the receive queue fills after a few datagrams
            notifier.status(f"tick {index}")

    # In a thread, so that a blocking send fails this test instead of hanging the run.
    sender = threading.Thread(target=flood, daemon=True)
    sender.start()
    sender.join(timeout=5.0)
    assert not sender.is_alive(), "a send blocked on a full notify socket"
    assert notifier.stats.failed > 0 and notifier.stats.last_error == "EAGAIN"
    assert notifier.stats.sent + notifier.stats.failed == 5000
    assert len(receiver.pending()) == notifier.stats.sent
    notifier.close()


def test_from_a_child_process_with_the_real_environment(
        fs_socket: tuple[dict[str, str], Receiver]) -> None:
    env, receiver = fs_socket
    code = ("from kernel.shell.systemd import ServiceNotifier\n"
            "n = ServiceNotifier.from_env()\n"
            "assert n.ready('up') and n.alive() and n.stopping()\n")
    child_env = {**os.environ, **env, "WATCHDOG_USEC": "4000000", "PYTHONPATH": str(ROOT)}
    child_env.pop("WATCHDOG_PID", None)
    subprocess.run([sys.executable, "-c", code], env=child_env, check=True, timeout=30)
    # READY restates the watchdog's timeout (a held start lengthened it for its bring-up).
    assert receiver.pending() == [b"READY=1\nSTATUS=up\nWATCHDOG_USEC=4000000", b"WATCHDOG=1",
                                  b"STOPPING=1"]


@pytest.mark.skipif(shutil.which("systemd-notify") is None, reason="systemd-notify not installed")
def test_same_bytes_as_systemd_notify(fs_socket: tuple[dict[str, str], Receiver]) -> None:
    env, receiver = fs_socket
    done = subprocess.run(["systemd-notify", "--no-block", "--ready", "--status=driver holding"],
                          env={**os.environ, **env}, capture_output=True, timeout=10, check=False)
    if done.returncode != 0:  # systemd older than 246 has no --no-block
        pytest.skip(f"systemd-notify failed: {done.stderr.decode().strip()}")
    theirs = receiver.recv()
    assert notify(env, READY=1, STATUS="driver holding")
    assert receiver.recv() == theirs
