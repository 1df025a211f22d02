"""Event loop helpers: uvloop by default, a clear fallback when it is missing."""

from __future__ import annotations

import asyncio
import sys

import pytest
import uvloop
from structlog.testing import capture_logs

from kernel.shell.loop import FALLBACK_MESSAGE, loop_name, new_event_loop, run


def test_uvloop_by_default_and_stock_on_request() -> None:
    for use_uvloop, kind, name in ((True, uvloop.Loop, "uvloop"), (False, None, "asyncio")):
        loop = new_event_loop(use_uvloop)
        try:
            assert loop_name(loop) == name
            assert kind is None or isinstance(loop, kind)
        finally:
            loop.close()


def test_fallback_is_announced(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "uvloop", None)  # makes `import uvloop` fail
    with capture_logs() as logs:
        loop = new_event_loop()
    try:
        assert loop_name(loop) == "asyncio"
    finally:
        loop.close()
    assert logs == [{"event": "uvloop_unavailable", "detail": FALLBACK_MESSAGE,
                     "log_level": "warning"}]


def test_run_returns_the_result_on_either_loop() -> None:
    async def main() -> str:
        await asyncio.sleep(0)
        return loop_name(asyncio.get_running_loop())

    assert run(main()) == "uvloop"
    assert run(main(), use_uvloop=False) == "asyncio"
