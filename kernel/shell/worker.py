"""Admission's long work off the control loop: a worker process that runs the core's jobs.

The core asks for a job (:class:`~kernel.core.effects.Compute`) when a chunk needs work that
would delay a control tick (:mod:`kernel.core.jobs`). On a live run the :class:`JobWorker`
sends it to a child process (``python -m kernel.shell.worker``) that built the same core
configuration from the same manifest sections, and feeds the result back to the core as a
:class:`~kernel.core.events.ComputedEvent` when it arrives; the journal records it, so a replay
needs no worker. The child runs on the other core: pinocchio's IK and the projection's Python
loops hold the GIL, so a thread would stall the loop instead.

Frames on the pipes are a 4-byte big-endian length and a MessagePack body. At most
``max_in_flight`` jobs are outstanding: beyond that, and when the worker has died, a job fails
at once (its chunk is refused, never admitted unchecked). The child exits when its stdin
closes, and is killed with its parent (``PR_SET_PDEATHSIG``).
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import json
import os
import signal
import struct
import subprocess
import sys
from typing import Any

import msgspec

from kernel.core.effects import Compute
from kernel.core.events import ComputedEvent
from kernel.core.jobs import Job, JobFailed, JobResult, run_job
from kernel.sections import ScenarioSections
from kernel.shell.gateway import CoreGateway
from kernel.shell.realtime import children_at_ordinary_priority

_HEADER = struct.Struct(">I")
_MAX_FRAME = 16 * 1024 * 1024
_PARENT_PID = "WARDEN_PARENT_PID"
_job_encoder = msgspec.msgpack.Encoder()
_result_decoder = msgspec.msgpack.Decoder(JobResult)


class InlineJobs:
    """Jobs run at once, on the caller's thread, at the instant they were asked for (lockstep
    runs on a virtual clock: the result is the same whoever computes it)."""

    def __init__(self, gateway: CoreGateway) -> None:
        self.gateway = gateway
        self.done = 0
        gateway.on(Compute, self._run)

    def _run(self, effect: Compute) -> None:
        config = self.gateway.core.config
        result = run_job(effect.job, config.limits, config.cartesian,
                         config.collision)
        self.done += 1
        self.gateway.feed(ComputedEvent(t=self.gateway.now_ns(), result=result))


class JobWorker:
    def __init__(self, gateway: CoreGateway, sections: ScenarioSections, source: str,
                 max_in_flight: int = 8) -> None:
        self.gateway = gateway
        self.max_in_flight = max_in_flight
        self.in_flight: set[int] = set()
        self.done = self.failed = 0
        self._init = json.dumps({"sections": sections.document(), "source": source}).encode()
        self._process: subprocess.Popen[bytes] | None = None
        self._buffer = bytearray()
        self._ended = asyncio.Event()
        gateway.on(Compute, self._submit)

    def start(self) -> None:
        # No preexec_fn: it would make subprocess fork() this large, memory-locked process
        # instead of vfork() (the child asks for PR_SET_PDEATHSIG itself, in main()). A
        # session of its own (setsid, which vfork allows): a terminal's Ctrl-C goes to
        # warden's process group, and must reach warden alone, which ends the run in order
        # and this worker by closing its stdin (the worker's own KeyboardInterrupt was a
        # traceback on every Ctrl-C).
        with children_at_ordinary_priority():  # the loop's priority is the loop's alone
            self._process = subprocess.Popen(
                [sys.executable, "-m", "kernel.shell.worker"], stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, env={**os.environ, _PARENT_PID: str(os.getpid())},
                start_new_session=True)
        self._send(self._init)

    async def run(self, started: Any = None) -> None:
        """Feed results to the core as they arrive, until cancelled or the worker dies.

        Raises:
            WorkerDied: the worker process ended (its in-flight jobs failed first).
        """
        if self._process is None:
            self.start()
        stdout = self._stdout()
        loop = asyncio.get_running_loop()
        loop.add_reader(stdout, self._readable, stdout)
        if started is not None:
            started()
        try:
            await self._ended.wait()
        finally:
            loop.remove_reader(stdout)
        code = self._process.poll() if self._process is not None else None
        raise WorkerDied(f"the job worker exited (status {code})")

    def close(self) -> None:
        process, self._process = self._process, None
        if process is None:
            return
        if process.stdin is not None:
            with contextlib.suppress(BrokenPipeError):  # a dead worker: its pipe is closed
                process.stdin.close()
        try:
            process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        if process.stdout is not None:
            process.stdout.close()

    def _submit(self, effect: Compute) -> None:
        job = effect.job
        if self._process is None or self._ended.is_set():
            self._fail(job, "the job worker is not running")
            return
        if len(self.in_flight) >= self.max_in_flight:
            self._fail(job, f"{self.max_in_flight} jobs already in flight")
            return
        self.in_flight.add(job.job_id)
        try:
            self._send(_job_encoder.encode(job))
        except OSError:
            self.in_flight.discard(job.job_id)
            self._fail(job, "the job worker is not running")

    def _send(self, body: bytes) -> None:
        stdin = self._process.stdin if self._process is not None else None
        if stdin is None:
            raise OSError("no worker")
        stdin.write(_HEADER.pack(len(body)) + body)
        stdin.flush()

    def _readable(self, fd: int) -> None:
        data = os.read(fd, 1 << 16)
        if not data:
            self._worker_ended()
            return
        self._buffer += data
        while len(self._buffer) >= _HEADER.size:
            (size,) = _HEADER.unpack_from(self._buffer)
            if len(self._buffer) < _HEADER.size + size:
                return
            body = bytes(self._buffer[_HEADER.size:_HEADER.size + size])
            del self._buffer[:_HEADER.size + size]
            self._deliver(_result_decoder.decode(body))

    def _deliver(self, result: JobResult) -> None:
        self.in_flight.discard(result.job_id)
        self.done += 1
        self.gateway.feed(ComputedEvent(t=self.gateway.now_ns(), result=result))

    def _fail(self, job: Job, detail: str) -> None:
        self.failed += 1
        self.gateway.feed(ComputedEvent(t=self.gateway.now_ns(),
                                        result=JobFailed(job_id=job.job_id, detail=detail)))

    def _worker_ended(self) -> None:
        for job_id in sorted(self.in_flight):
            self.failed += 1
            self.gateway.feed(ComputedEvent(t=self.gateway.now_ns(), result=JobFailed(
                job_id=job_id, detail="the job worker stopped")))
        self.in_flight.clear()
        self._ended.set()

    def _stdout(self) -> int:
        if self._process is None or self._process.stdout is None:
            raise WorkerDied("the job worker did not start")
        return self._process.stdout.fileno()


class WorkerDied(RuntimeError):
    """The job worker process ended; its jobs failed and their chunks were refused."""


def _die_with_parent() -> None:
    """In the worker: SIGTERM when warden dies; exit at once if it already has."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    expected = os.environ.get(_PARENT_PID, "")
    if expected.isdigit() and os.getppid() != int(expected):
        sys.exit("warden's job worker: warden is gone")


# -- the child ---------------------------------------------------------------------------------


def _read_frame(stream: Any) -> bytes | None:
    header = stream.read(_HEADER.size)
    if len(header) < _HEADER.size:
        return None
    (size,) = _HEADER.unpack(header)
    if size > _MAX_FRAME:
        raise ValueError(f"frame of {size} bytes")
    body = stream.read(size)
    return body if len(body) == size else None


def main() -> int:
    """The worker: build the configuration, then answer jobs until stdin closes."""
    _die_with_parent()
    from kernel.config.build import build_config
    from kernel.scenario.fields import Where

    stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
    init = _read_frame(stdin)
    if init is None:
        return 0
    setup = json.loads(init)
    config = build_config(setup["sections"], Where(setup["source"], ""))
    decoder = msgspec.msgpack.Decoder(Job)
    encoder = msgspec.msgpack.Encoder()
    while (frame := _read_frame(stdin)) is not None:
        job = decoder.decode(frame)
        try:
            result: JobResult = run_job(job, config.limits, config.cartesian,
                                        config.collision)
        except ValueError as error:
            result = JobFailed(job_id=job.job_id, detail=str(error))
        body = encoder.encode(result)
        stdout.write(_HEADER.pack(len(body)) + body)
        stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
