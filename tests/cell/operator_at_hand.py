"""A human at the operator socket during a real-device run or trial (warden refuses the
simulated operator with a real device): under a recoverable fallback, once the arm has come to
rest, accept recovery. A chunk refused on the loaded 2-core test machine (the queue ran dry
and the late chunk's first step needed a projection past the phase's bound, or its segment's
clearance bound dipped under the margin) then costs a retreat or a hold, not the cycle, as it
would with an operator at the cell."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

from kernel.cli_operator import send
from stubs.cell.operator import RECOVERABLE
from stubs.fault_control import inject
from stubs.ur_controller.launch import EmulatedController

AT_REST = 0.01
"""rad/s: the fastest joint of an arm at rest."""


@contextlib.contextmanager
def operator_at_hand(socket: Path, at_rest: Callable[[], bool]) -> Iterator[list[str]]:
    """Yields the fallbacks recovered from (the test reports them)."""
    recovered: list[str] = []
    done = threading.Event()

    def accept() -> None:
        while not done.wait(0.25):
            with contextlib.suppress(OSError, ValueError, RuntimeError):
                mode = send(str(socket), "status", 1.0).get("mode")
                if mode in RECOVERABLE and at_rest() and send(
                        str(socket), "accept-recovery", 1.0).get("ok"):
                    recovered.append(str(mode))

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    try:
        yield recovered
    finally:
        done.set()
        thread.join()


def control_of(emulator: EmulatedController) -> tuple[str, int]:
    """A launched UR controller emulator's fault and world port."""
    return emulator.host, int(emulator.info["control_port"])


def emulator_at_rest(control: tuple[str, int]) -> Callable[[], bool]:
    """Whether an emulator's plant (its fault port's ``ground_truth``) has come to rest."""
    return lambda: max(map(abs, inject(control, "ground_truth")["qd"])) < AT_REST
