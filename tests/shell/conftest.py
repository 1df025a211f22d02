"""Shell tests: the primitives run on the stock loop and on uvloop; no test may leak tasks."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable, Mapping

import pytest
import uvloop

_BOTH_LOOPS = frozenset({"test_timer", "test_supervisor", "test_operator_socket"})


def pytest_asyncio_loop_factories(
    config: pytest.Config, item: pytest.Item
) -> Mapping[str, Callable[[], asyncio.AbstractEventLoop]]:
    # The shell primitives must behave the same on both loops (warden runs uvloop; a test or a
    # tool may not). Other modules in this folder get the stock loop, pytest-asyncio's default
    # (the hook may not return None or an empty mapping).
    if item.path.stem not in _BOTH_LOOPS:
        return {"asyncio": asyncio.new_event_loop}
    return {"asyncio": asyncio.new_event_loop, "uvloop": uvloop.new_event_loop}


@pytest.fixture(autouse=True)
async def no_leaked_tasks() -> AsyncIterator[None]:
    before = asyncio.all_tasks()
    yield
    current = asyncio.current_task()
    leaked = [t for t in asyncio.all_tasks() - before if t is not current and not t.done()]
    for task in leaked:
        task.cancel()
    assert not leaked, f"tasks leaked by the test: {leaked}"
