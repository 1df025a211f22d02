"""The UR driver's stop, under way on the device thread while the control loop's ticks go on.

A stop (servoStop or speedStop, stopJ, the watchdog lengthened around them) is several blocking
round trips to the control script, 50 to 120 ms on the emulator and the deceleration itself on
an arm: sent every period it held the loop to ~200 Hz, and awaited once it stalls the loop. So
it runs on the device thread while the ticks go on; until it is done, reads repeat the last
sample (not fresh) and STOP is answered without a call. Any other command waits for it; its
failure is raised by the next call.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from drivers.device_thread import DeviceThread


class BackgroundStop:
    def __init__(self, driver_error: Callable[[BaseException], BaseException]) -> None:
        self._driver_error = driver_error
        """The driver's error for what the stop raised (link trouble)."""
        self.call: asyncio.Future[object] | None = None
        """A stop under way on the device thread: the loop's ticks go on meanwhile."""
        self.stopped = False
        """The driver's stop brought the arm to rest and no command has moved it since."""

    def start(self, thread: DeviceThread, timeout_s: float, stop: Callable[[], object]) -> None:
        self.stopped = False
        self.call = thread.submit(timeout_s, stop)

    def under_way(self) -> bool:
        """Whether a stop is still under way; one that failed raises its error here."""
        call = self.call
        if call is None or not call.done():
            return call is not None
        self.call = None
        error = call.exception()
        if error is not None:
            raise self._driver_error(error) from error
        self.stopped = True
        return False

    async def finished(self) -> None:
        """A command other than STOP (a hold after a recovery) starts once the stop is done."""
        if self.call is not None:
            await asyncio.wait([self.call])
            self.under_way()
