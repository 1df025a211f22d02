"""Ending a run from outside: SIGINT (Ctrl-C at a terminal) and SIGTERM (``systemctl stop``).

Either one ends the run through its ordinary path: the tick under way completes, no further
tick starts, the arm is held and the device closed, the journal flushed and closed, and the
cycle under way is counted as attempted and not verified. A signal during start-up (the
device's bring-up, the policy server's start) is kept and honoured before the first tick.

The handlers only note the signal. They are plain Python handlers, which run between two
bytecodes of the main thread, so they also reach a lockstep loop that never yields to the event
loop; the loop looks at the note before each tick. They stay installed until the run's shutdown
is over: a second Ctrl-C while the arm is being held changes nothing. The job worker and the
stand-ins' processes (policy server, emulators) run in sessions of their own, so a terminal's
Ctrl-C reaches warden alone, which ends them itself.

``warden run`` then exits with 128 + the signal's number (:data:`EXIT_INTERRUPTED`: 130 for
SIGINT, 143 for SIGTERM; README.md, docs/operations.md).
"""

from __future__ import annotations

import signal
import threading
from types import FrameType, TracebackType
from typing import Any

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
EXIT_INTERRUPTED = {sig.name: 128 + int(sig) for sig in STOP_SIGNALS}
"""Exit code of a run ended by a signal, by the signal's name: the shell's convention."""


class StopSignals:
    """SIGINT and SIGTERM noted while the ``with`` block runs (main thread only; elsewhere no
    signal can be handled, and none is noted)."""

    def __init__(self) -> None:
        self.received: signal.Signals | None = None
        """The first stop signal received."""
        self._previous: dict[signal.Signals, Any] = {}

    @property
    def requested(self) -> bool:
        return self.received is not None

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            # A signal the parent set to be ignored stays ignored (as Python leaves an ignored
            # SIGINT alone: a shell's background job is not for its terminal's Ctrl-C).
            self._previous = {sig: signal.signal(sig, self._note) for sig in STOP_SIGNALS
                              if signal.getsignal(sig) is not signal.SIG_IGN}
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}

    def _note(self, signum: int, _: FrameType | None) -> None:
        if self.received is None:
            self.received = signal.Signals(signum)
