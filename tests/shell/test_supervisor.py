"""Supervisor: started handshake, failure reporting, critical stop, restarts, ordered shutdown."""

from __future__ import annotations

import asyncio
import io
import json
from collections.abc import Callable

import pytest
import structlog

from kernel.shell.logging import configure_logging
from kernel.shell.supervisor import (
    MAX_MESSAGE,
    ChildState,
    RestartPolicy,
    Started,
    StartError,
    Supervisor,
    describe,
    failure_fields,
)

FAST = RestartPolicy(max_restarts=3, initial_backoff_s=0.0005, max_backoff_s=0.002)


class Boom(Exception):
    pass


class Recorder:
    def __init__(self) -> None:
        self.events: list[str] = []
        self.failures: list[tuple[str, str]] = []

    def on_failure(self, name: str, exc: BaseException) -> None:
        self.failures.append((name, type(exc).__name__))

    def service(self, name: str, *, slow_finally: asyncio.Event | None = None
                ) -> Callable[[Started], object]:
        """A child that runs until cancelled and records its finally (a driver hold())."""
        async def run(started: Started) -> None:
            self.events.append(f"{name}:started")
            started(name)
            try:
                await asyncio.Event().wait()
            finally:
                if slow_finally is not None:
                    await slow_finally.wait()
                self.events.append(f"{name}:finally")
        return run


async def test_start_returns_after_started_with_its_value() -> None:
    rec = Recorder()

    async def child(started: Started) -> None:
        for step in range(3):  # not ready at once: start() must wait
            rec.events.append(f"setup{step}")
            await asyncio.sleep(0)
        started({"port": 7})
        await asyncio.Event().wait()

    async with Supervisor(on_failure=rec.on_failure) as sup:
        value = await sup.start("child", child, critical=True)
        rec.events.append("start returned")
        assert value == {"port": 7}
        assert sup.children()[0].state is ChildState.RUNNING
        await sup.shutdown()
    assert rec.events == ["setup0", "setup1", "setup2", "start returned"]
    assert rec.failures == []


async def test_critical_failure_reports_stops_siblings_in_reverse_and_surfaces() -> None:
    rec = Recorder()
    crash = asyncio.Event()

    async def critical(started: Started) -> None:
        started()
        await crash.wait()
        raise Boom("motor overheated, frame 123456")

    with pytest.raises(ExceptionGroup) as caught:
        async with Supervisor(on_failure=rec.on_failure) as sup:
            await sup.start("a", rec.service("a"), critical=False)
            await sup.start("b", rec.service("b"), critical=False)
            await sup.start("control", critical, critical=True)
            crash.set()
            await asyncio.Event().wait()  # cancelled by the failure
    assert [type(e) for e in caught.value.exceptions] == [Boom]
    assert rec.failures == [("control", "Boom")]
    assert rec.events == ["a:started", "b:started", "b:finally", "a:finally"]
    assert sup.children()[2].state is ChildState.FAILED


async def test_critical_failure_before_started_surfaces() -> None:
    rec = Recorder()

    async def broken(started: Started) -> None:
        raise Boom("no device")

    with pytest.raises(ExceptionGroup) as caught:
        async with Supervisor(on_failure=rec.on_failure) as sup:
            await sup.start("driver", broken, critical=True)
            rec.events.append("not reached")
    assert caught.value.subgroup(Boom) is not None
    assert rec.failures == [("driver", "Boom")]
    assert rec.events == []


async def test_non_critical_failure_before_started_raises_start_error() -> None:
    rec = Recorder()

    async def broken(started: Started) -> None:
        raise Boom("no device")

    async with Supervisor(on_failure=rec.on_failure, restart=FAST) as sup:
        with pytest.raises(StartError) as caught:
            await sup.start("camera", broken, critical=False)
    assert isinstance(caught.value.__cause__, Boom)
    assert rec.failures == [("camera", "Boom")]
    assert sup.children()[0].state is ChildState.STOPPED


async def test_returning_without_started_is_a_failure() -> None:
    rec = Recorder()

    async def lazy(started: Started) -> None:
        return None

    async with Supervisor(on_failure=rec.on_failure) as sup:
        with pytest.raises(StartError):
            await sup.start("lazy", lazy, critical=False)
    assert rec.failures == [("lazy", "StartError")]


async def test_start_timeout_cancels_the_child() -> None:
    rec = Recorder()

    async def never_ready(started: Started) -> None:
        try:
            await asyncio.Event().wait()
        finally:
            rec.events.append("cancelled")

    async with Supervisor(on_failure=rec.on_failure, start_timeout_s=0.01) as sup:
        with pytest.raises(StartError) as caught:
            await sup.start("slow", never_ready, critical=True)
    assert isinstance(caught.value.__cause__, TimeoutError)
    assert rec.failures == [("slow", "TimeoutError")]
    assert rec.events == ["cancelled"]


async def test_non_critical_child_restarts_with_backoff() -> None:
    rec = Recorder()
    runs = 0

    async def flaky(started: Started) -> None:
        nonlocal runs
        runs += 1
        started()
        if runs <= 2:
            raise Boom(f"attempt {runs}")
        await asyncio.Event().wait()

    async with Supervisor(on_failure=rec.on_failure, restart=FAST) as sup:
        await sup.start("flaky", flaky, critical=False)
        while runs < 3:
            await asyncio.sleep(0.001)
        await asyncio.sleep(0)
        status = sup.children()[0]
        await sup.shutdown()
    assert rec.failures == [("flaky", "Boom"), ("flaky", "Boom")]
    assert (status.restarts, status.state, status.last_failure) == (2, ChildState.RUNNING, "Boom")


async def test_restarts_are_bounded_and_siblings_survive() -> None:
    rec = Recorder()

    async def always_fails(started: Started) -> None:
        started()
        raise Boom("again")

    once = RestartPolicy(max_restarts=1, initial_backoff_s=0.0005)
    async with Supervisor(on_failure=rec.on_failure) as sup:
        await sup.start("steady", rec.service("steady"), critical=True)
        await sup.start("bad", always_fails, critical=False, restart=once)
        while sup.children()[1].state is not ChildState.STOPPED:
            await asyncio.sleep(0.001)
        assert sup.children()[0].state is ChildState.RUNNING
        await sup.shutdown()
    assert rec.failures == [("bad", "Boom"), ("bad", "Boom")]
    assert sup.children()[1].restarts == 1
    assert rec.events == ["steady:started", "steady:finally"]


async def test_shutdown_runs_finally_blocks_in_reverse_order() -> None:
    rec = Recorder()
    async with Supervisor(on_failure=rec.on_failure) as sup:
        for name in ("driver", "recorder", "control"):
            await sup.start(name, rec.service(name), critical=True)
        await sup.shutdown()
        await sup.shutdown()
    finals = [e for e in rec.events if e.endswith("finally")]
    assert finals == ["control:finally", "recorder:finally", "driver:finally"]
    assert {c.state for c in sup.children()} == {ChildState.STOPPED}
    assert rec.failures == []


async def test_shutdown_is_shielded_from_its_callers_cancellation() -> None:
    rec = Recorder()
    release = asyncio.Event()
    async with Supervisor(on_failure=rec.on_failure) as sup:
        await sup.start("driver", rec.service("driver"), critical=True)
        await sup.start("control", rec.service("control", slow_finally=release), critical=True)
        async with asyncio.TaskGroup() as group:
            stopping = group.create_task(sup.shutdown())
            for _ in range(5):
                await asyncio.sleep(0)
            stopping.cancel()  # the caller gives up while control's hold() is still running
            for _ in range(5):
                await asyncio.sleep(0)
            assert not stopping.done()  # still finishing the ordered stop
            release.set()
    assert stopping.cancelled()  # the cancellation was re-raised, not swallowed
    assert rec.events[-2:] == ["control:finally", "driver:finally"]


async def test_an_error_in_the_body_stops_children_in_reverse_order() -> None:
    rec = Recorder()
    with pytest.raises(ExceptionGroup) as caught:
        async with Supervisor(on_failure=rec.on_failure) as sup:
            await sup.start("a", rec.service("a"), critical=True)
            await sup.start("b", rec.service("b"), critical=False)
            raise Boom("in the body")
    assert caught.value.subgroup(Boom) is not None
    assert rec.events[-2:] == ["b:finally", "a:finally"]
    assert rec.failures == []


def test_backoff_is_capped() -> None:
    policy = RestartPolicy(max_restarts=10, initial_backoff_s=0.1, max_backoff_s=0.5)
    assert [policy.backoff_s(n) for n in range(5)] == [0.1, 0.2, 0.4, 0.5, 0.5]


def test_a_failure_is_described_with_its_message_and_every_sub_exception() -> None:
    try:
        raise ExceptionGroup("unhandled errors in a TaskGroup", [
            OverflowError("int too big to convert"),
            ExceptionGroup("inner", [ValueError("x" * 500), KeyError("k")]),
        ])
    except ExceptionGroup as group:
        text = describe(group)
        fields = failure_fields(group)
    assert text.startswith("ExceptionGroup of 3: OverflowError: int too big to convert; ")
    assert "KeyError: 'k'" in text and len(text) < 600  # each message bounded
    assert fields["error"] == "ExceptionGroup"
    assert fields["sub_errors"] == ["OverflowError: int too big to convert",
                                    f"ValueError: {'x' * MAX_MESSAGE}...", "KeyError: 'k'"]
    assert describe(Boom("attempt 1")) == "Boom: attempt 1"
    assert describe(Boom()) == "Boom"


async def test_a_failed_child_is_logged_with_what_failed_not_only_its_type() -> None:
    stream = io.StringIO()
    configure_logging("INFO", stream)
    try:
        async def crashes(started: Started) -> None:
            started()
            async with asyncio.TaskGroup() as tasks:
                tasks.create_task(_raise(OverflowError("offset out of range")))

        async with Supervisor() as sup:
            await sup.start("link", crashes, critical=False)
            await asyncio.sleep(0.01)
            await sup.shutdown()
    finally:
        structlog.reset_defaults()
    (line,) = [json.loads(text) for text in stream.getvalue().splitlines()]
    assert (line["event"], line["child"], line["error"]) == ("child_failed", "link",
                                                             "ExceptionGroup")
    assert line["sub_errors"] == ["OverflowError: offset out of range"]


async def _raise(error: Exception) -> None:
    raise error
