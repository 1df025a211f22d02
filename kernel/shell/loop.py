"""Event loop selection: uvloop when installed, else the stock loop with one clear warning.

The measured tail of a 500 Hz loop is several times worse on the stock loop (bench/loop.py
measures both), so falling back is allowed but never silent.
"""

from __future__ import annotations

import asyncio
import importlib
from collections.abc import Callable, Coroutine
from typing import Any, TypeVar

import structlog

T = TypeVar("T")
_log = structlog.get_logger("kernel.shell.loop")

FALLBACK_MESSAGE = ("uvloop is not available; using the stock asyncio loop (expect a worse timing "
                    "tail): install uvloop")


def uvloop_factory() -> Callable[[], asyncio.AbstractEventLoop] | None:
    """uvloop's loop constructor, or None when uvloop cannot be imported."""
    try:
        uvloop = importlib.import_module("uvloop")
    except ImportError:
        return None
    return uvloop.new_event_loop  # type: ignore[no-any-return]


def loop_factory(use_uvloop: bool = True) -> Callable[[], asyncio.AbstractEventLoop]:
    """The constructor :func:`new_event_loop` uses; logs the fallback once per call."""
    if not use_uvloop:
        return asyncio.new_event_loop
    factory = uvloop_factory()
    if factory is None:
        _log.warning("uvloop_unavailable", detail=FALLBACK_MESSAGE)
        return asyncio.new_event_loop
    return factory


def new_event_loop(use_uvloop: bool = True) -> asyncio.AbstractEventLoop:
    return loop_factory(use_uvloop)()


def loop_name(loop: asyncio.AbstractEventLoop) -> str:
    """``"uvloop"`` or ``"asyncio"``: for a report or a log line."""
    return "uvloop" if type(loop).__module__.startswith("uvloop") else "asyncio"


def run(main: Coroutine[Any, Any, T], *, use_uvloop: bool = True,
        debug: bool | None = None) -> T:
    """``asyncio.run`` on the loop :func:`new_event_loop` picks."""
    with asyncio.Runner(debug=debug, loop_factory=loop_factory(use_uvloop)) as runner:
        return runner.run(main)
