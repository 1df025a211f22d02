"""The safety monitor stops on SIGTERM however often its loop waits: the stop a signal handler
requests takes no lock.

A handler runs in the main thread between two of its bytecodes, and the monitor's main thread
spends its life waiting between two checks. When that wait was a ``threading.Event``'s and the
handler called ``set()``, a signal landing while ``wait()`` held the Event's lock deadlocked the
monitor: a monitor a test had stopped stayed at real-time priority 60 until killed. The same
loop with that Event hangs within a few of these trials (kill -9 needed: its SIGTERM handler
is the hung one).
"""

from __future__ import annotations

import subprocess
import sys

_TRIALS = 200
_LOOP = f"""
import os, signal, threading
from kernel.safety.service import SignalledStop, stop_on_signals
for trial in range({_TRIALS}):
    stopping = SignalledStop()
    with stop_on_signals(stopping):
        threading.Timer(0.002, os.kill, (os.getpid(), signal.SIGTERM)).start()
        while not stopping.is_set():
            stopping.wait(0)  # the monitor's wait, as often as it can be called
print("stopped", trial + 1)
"""


def test_a_stop_signal_ends_the_monitors_wait_every_time() -> None:
    child = subprocess.Popen([sys.executable, "-c", _LOOP], stdout=subprocess.PIPE, text=True)
    try:
        out, _ = child.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        child.kill()  # SIGKILL: a hung handler would take a SIGTERM as one more stop request
        child.communicate()
        raise AssertionError("a SIGTERM left the monitor's wait hung") from None
    assert child.returncode == 0 and out.split() == ["stopped", str(_TRIALS)]
