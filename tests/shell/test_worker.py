"""The job worker: admission's long work in a child process, its results fed to the core.

The worker builds its configuration from the manifest sections a journal carries, so its answer
to a job must be the answer the core would compute inline, bit for bit (a replay feeds the
recorded result and never recomputes it). A worker that is full or gone refuses at once: the
chunk is refused, never admitted unchecked, and a dead worker ends the run."""

from __future__ import annotations

import asyncio
import os
import signal
from collections.abc import Callable
from typing import Any

import msgspec
import numpy as np
import pytest

from kernel.core.effects import Compute
from kernel.core.events import ComputedEvent, Event
from kernel.core.jobs import JobFailed, MapJob, MapResult, ProjectJob, run_job
from kernel.manifest import Manifest
from kernel.shell.worker import JobWorker, WorkerDied
from tests.cell.harness import manifest

CARTESIAN = "sim-ur5e-cartesian.toml"


class _Gateway:
    """The two doors of the run's gateway a worker uses: effects in, events out."""

    def __init__(self) -> None:
        self.handlers: dict[type, Callable[[Any], None]] = {}
        self.fed: list[Event] = []

    def on(self, kind: type, handler: Callable[[Any], None]) -> None:
        self.handlers[kind] = handler

    def feed(self, event: Event) -> None:
        self.fed.append(event)

    def now_ns(self) -> int:
        return len(self.fed)

    def ask(self, job: MapJob | ProjectJob) -> None:
        self.handlers[Compute](Compute(job=job))

    def results(self) -> list[Any]:
        return [event.result for event in self.fed if isinstance(event, ComputedEvent)]


@pytest.fixture(scope="module")
def cartesian() -> Manifest:
    return manifest(CARTESIAN)


def _worker(loaded: Manifest, gateway: _Gateway, max_in_flight: int = 8) -> JobWorker:
    return JobWorker(gateway, loaded.sections, str(loaded.path),  # type: ignore[arg-type]
                     max_in_flight=max_in_flight)


def _map_job(loaded: Manifest, job_id: int) -> MapJob:
    """A chunk of TCP displacements (the Cartesian cell's action) from the home pose, down
    into the workspace box (home is above it)."""
    steps = np.linspace(0.08, 0.10, 20)
    actions = tuple((0.0, 0.0, -float(s), 0.0, 0.0, 0.0) for s in steps)
    return MapJob(job_id=job_id, actions=actions, anchor=tuple(loaded.core.initial_q.tolist()))


async def _until(gateway: _Gateway, count: int, worker: JobWorker) -> None:
    async with asyncio.timeout(30):
        runner = asyncio.create_task(worker.run())
        try:
            while len(gateway.results()) < count:
                await asyncio.sleep(0.01)
        finally:
            runner.cancel()
            await asyncio.gather(runner, return_exceptions=True)


async def test_the_worker_answers_what_the_core_would_compute_inline(
        cartesian: Manifest) -> None:
    gateway = _Gateway()
    worker = _worker(cartesian, gateway)
    worker.start()
    try:
        jobs = [_map_job(cartesian, 1), _map_job(cartesian, 2)]
        for job in jobs:
            gateway.ask(job)
        await _until(gateway, len(jobs), worker)
    finally:
        worker.close()
    config = cartesian.core
    encode = msgspec.msgpack.encode
    for job, result in zip(jobs, gateway.results(), strict=True):
        assert isinstance(result, MapResult) and result.joints is not None
        assert encode(result) == encode(run_job(job, config.limits, config.cartesian))
    assert (worker.done, worker.failed, worker.in_flight) == (2, 0, set())


async def test_a_job_beyond_the_in_flight_limit_is_refused_at_once(cartesian: Manifest) -> None:
    gateway = _Gateway()
    worker = _worker(cartesian, gateway, max_in_flight=1)
    worker.start()
    try:
        gateway.ask(_map_job(cartesian, 1))
        gateway.ask(_map_job(cartesian, 2))
        (refused,) = gateway.results()  # before the worker has answered anything
        assert isinstance(refused, JobFailed) and refused.job_id == 2
        assert "1 jobs already in flight" in refused.detail
        await _until(gateway, 2, worker)
    finally:
        worker.close()
    assert isinstance(gateway.results()[1], MapResult) and gateway.results()[1].job_id == 1


async def test_a_dead_worker_fails_its_jobs_and_ends_the_run(cartesian: Manifest) -> None:
    gateway = _Gateway()
    worker = _worker(cartesian, gateway)
    worker.start()
    process = worker._process  # the child this test kills
    assert process is not None
    try:
        os.kill(process.pid, signal.SIGKILL)
        process.wait()
        gateway.ask(_map_job(cartesian, 7))
        with pytest.raises(WorkerDied):
            async with asyncio.timeout(10):
                await worker.run()
        gateway.ask(_map_job(cartesian, 8))  # after the end: refused at once
    finally:
        worker.close()
    results = gateway.results()
    assert [r.job_id for r in results] == [7, 8]
    assert all(isinstance(r, JobFailed) for r in results)
    assert worker.in_flight == set() and worker.done == 0
