"""One dedicated thread per device for blocking SDK calls, with a deadline on every call."""

from __future__ import annotations

import asyncio
import functools
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from drivers.base import DriverTimeout

T = TypeVar("T")


class DeviceThread:
    """Runs blocking calls for one device, in order, on its own thread.

    A vendor port is rarely thread-safe, so all calls for one device share a single worker.
    A call that exceeds its deadline raises :class:`DriverTimeout`; the worker may still be
    blocked inside the SDK, so the caller must treat the device as faulted.
    """

    def __init__(self, device: str) -> None:
        self.device = device
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"dev-{device}")
        self._closed = False

    async def run(self, timeout_s: float, fn: Callable[..., T], *args: object) -> T:
        if self._closed:
            raise RuntimeError(f"{self.device}: device thread is closed")
        loop = asyncio.get_running_loop()
        future = loop.run_in_executor(self._executor, functools.partial(fn, *args))
        try:
            async with asyncio.timeout(timeout_s):
                return await future
        except TimeoutError:
            name = getattr(fn, "__name__", "call")
            raise DriverTimeout(self.device, f"{name} took longer than {timeout_s:.3f} s") from None

    def close(self) -> None:
        """Stop accepting calls; a call stuck in the SDK is abandoned, not waited for."""
        if not self._closed:
            self._closed = True
            self._executor.shutdown(wait=False, cancel_futures=True)
