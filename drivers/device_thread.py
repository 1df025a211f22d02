"""One dedicated thread per device for blocking SDK calls, with a deadline on every call.

A vendor port is rarely thread-safe, so all calls for one device run in order on a single
worker. The worker is a daemon thread fed by a queue; a result comes back to the event loop
with one ``call_soon_threadsafe`` (cheaper than an executor future, and the hand-off is most of
a driver call's cost). A call that exceeds its deadline raises :class:`DriverTimeout`; the
worker may still be stuck inside the SDK, so the caller must treat the device as faulted. The
thread is a daemon: a call abandoned inside an SDK never blocks interpreter exit.
"""

from __future__ import annotations

import asyncio
import contextlib
import queue
import threading
from collections.abc import Callable
from typing import Any, TypeVar

from drivers.base import DriverTimeout

T = TypeVar("T")
_STOP = object()


class DeviceThread:
    def __init__(self, device: str) -> None:
        self.device = device
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._closed = False
        self._thread = threading.Thread(target=self._work, name=f"dev-{device}", daemon=True)
        self._thread.start()

    async def run(self, timeout_s: float, fn: Callable[..., T], *args: object) -> T:
        if self._closed:
            raise RuntimeError(f"{self.device}: device thread is closed")
        loop = asyncio.get_running_loop()
        future: asyncio.Future[T] = loop.create_future()
        self._queue.put((fn, args, future, loop))
        try:
            async with asyncio.timeout(timeout_s) as deadline:
                return await future
        except TimeoutError:
            if not deadline.expired():
                raise  # the call itself raised a TimeoutError: keep its own message
            name = getattr(fn, "__name__", "call")
            raise DriverTimeout(self.device, f"{name} took longer than {timeout_s:.3f} s") from None

    def submit(self, timeout_s: float, fn: Callable[..., T], *args: object) -> asyncio.Future[T]:
        """Queue a call without waiting for it (a stop the control loop must not wait out):
        the caller looks at the future on later ticks. Past ``timeout_s`` it fails with
        :class:`DriverTimeout`, as :meth:`run` would; its error counts as retrieved, so a
        caller that closes before looking leaves no warning behind."""
        if self._closed:
            raise RuntimeError(f"{self.device}: device thread is closed")
        loop = asyncio.get_running_loop()
        future: asyncio.Future[T] = loop.create_future()
        name = getattr(fn, "__name__", "call")
        expired = DriverTimeout(self.device, f"{name} took longer than {timeout_s:.3f} s")
        timer = loop.call_later(timeout_s, _expire, future, expired)
        future.add_done_callback(lambda done: (timer.cancel(), _retrieved(done)))
        self._queue.put((fn, args, future, loop))
        return future

    def close(self) -> None:
        """Stop accepting calls; a call stuck in the SDK is abandoned, not waited for."""
        if not self._closed:
            self._closed = True
            self._queue.put(_STOP)

    def _work(self) -> None:
        while True:
            item = self._queue.get()
            if item is _STOP:
                return
            fn, args, future, loop = item
            try:
                result = fn(*args)
            except BaseException as error:  # delivered to the awaiting coroutine, not lost
                _deliver(loop, future, error=error)
            else:
                _deliver(loop, future, result=result)


def _deliver(loop: asyncio.AbstractEventLoop, future: asyncio.Future[Any], *,
             result: Any = None, error: BaseException | None = None) -> None:
    def settle() -> None:
        if future.done():  # the caller gave up (deadline or cancellation)
            return
        if error is not None:
            future.set_exception(error)
        else:
            future.set_result(result)

    with contextlib.suppress(RuntimeError):  # the loop is closed: nobody is waiting any more
        loop.call_soon_threadsafe(settle)


def _expire(future: asyncio.Future[Any], error: BaseException) -> None:
    if not future.done():
        future.set_exception(error)


def _retrieved(future: asyncio.Future[Any]) -> None:
    if not future.cancelled():
        future.exception()
