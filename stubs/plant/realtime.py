"""Step a plant against the wall clock on a background thread (for emulator processes only).

Emulators are the robot side: they are not warden's control loop, so a plain thread with an
absolute-deadline sleep is good enough here. Commands and reads take ``lock``.
"""

from __future__ import annotations

import threading
import time

from stubs.plant.base import Plant


class RealtimeStepper:
    def __init__(self, plant: Plant) -> None:
        self.plant = plant
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._paused = threading.Event()
        self._thread = threading.Thread(target=self._run, name="plant", daemon=True)

    def start(self) -> RealtimeStepper:
        self._thread.start()
        return self

    def pause(self, paused: bool) -> None:
        """Freeze physics (used to emulate a stalled controller)."""
        if paused:
            self._paused.set()
        else:
            self._paused.clear()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)

    def _run(self) -> None:
        period = self.plant.timestep_ns
        deadline = time.monotonic_ns()
        while not self._stop.is_set():
            deadline += period
            now = time.monotonic_ns()
            if deadline > now:
                time.sleep((deadline - now) * 1e-9)
            else:
                deadline = now  # fell behind (VM pause): do not try to catch up in a burst
            if not self._paused.is_set():
                with self.lock:
                    self.plant.step(1)
