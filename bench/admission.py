"""Admission cost and replay speed of the assurance core (issue 2 targets).

Prints, for 50x6 and 50x7 chunks (and 50x7 with the shipped cell's [geometry]):
  - wire decode only (msgspec MessagePack, actions as raw bytes),
  - a stdlib-json decode of the same chunk (what a json-based client pays just to parse),
  - full admission: decode + every gate + merge + projection + queue commit + log line,
  - full admission of a chunk that needs the exact (sequential) projection,
as p50 / p99 in microseconds; with [geometry], the admission's part on the control loop (every
step the chunk takes, its clearance job's result included) and the clearance job itself (which
a live run sends to the job worker), both against the same chunks without geometry in the same
run; and the replay speed of a 60 s scenario at a 2 ms control period
as a multiple of real time. Figures are printed, never asserted (the machine is shared and
noisy); compare the ratios within one run. Where Linux perf events are available, the user-space
instructions and cycles of one full admission are printed too: the instruction count does not
move with the machine's load, so it is the figure to compare across runs and commits.

    .venv/bin/python bench/admission.py [--samples 3000]
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make the repository's tools importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import msgspec
import numpy as np

from assurance.envelope import decode_wire_chunk, to_wire
from assurance.event_chunk import decode_event_chunk
from bench.counters import Counters, open_counters
from kernel.config.build import build_config
from kernel.core.effects import Compute
from kernel.core.events import (
    ChunkEvent,
    ComputedEvent,
    Event,
    ObservationEvent,
    StateEvent,
    TickEvent,
)
from kernel.core.jobs import run_job
from kernel.core.lines import Line, encode
from kernel.core.runtime import Core
from kernel.scenario.fields import Where
from kernel.scenario.load import Scenario
from tools.scenarios.base import IDENTITY, ScenarioSpec, phases, robot
from tools.scenarios.catalog_collision import GEOMETRY

MS = 1_000_000
HORIZON = 50
DT_MS = 10


def _config(dim: int, geometry: bool = False):  # type: ignore[no-untyped-def]
    generous = phases()
    generous["PRE_CONTACT"].update(max_projection=0.5, max_divergence=0.5)
    spec = ScenarioSpec(name="bench", description="", events=[], until=0, expect=[],
                        gripper=dim == 7, phases=generous,
                        robot={**robot(dim == 7), "kinematics": "ur5e"} if geometry else None,
                        geometry=GEOMETRY if geometry else None)
    return build_config(spec.document(), Where("bench", ""))


def _fields(index: int, t_ms: float, start: np.ndarray, fast: bool) -> dict:
    steps = np.arange(1, HORIZON + 1)[:, None] * (0.012 if fast else 0.002)
    actions = start + steps
    if start.shape[0] == 7:
        actions[:, 6] = 0.0
    return {
        "chunk_id": f"C{index}", "sequence": index, "queue_epoch": 0, **IDENTITY,
        "task_phase": "PRE_CONTACT", "observation_id": f"O{index}",
        "observation_event_time": t_ms, "clock_domain": "client", "inference_start": t_ms + 1,
        "first_action_time": t_ms + 2, "action_dt": DT_MS, "actions": actions.tolist(),
    }


def _percentiles(samples: list[int]) -> tuple[float, float]:
    ordered = sorted(samples)
    return ordered[len(ordered) // 2] / 1e3, ordered[int(len(ordered) * 0.99)] / 1e3


def _admission(
    dim: int, samples: int, fast: bool, counters: Counters | None = None
) -> dict[str, tuple[float, float]]:
    config = _config(dim)
    core = Core(config)
    start = config.initial_q.copy()
    encoder = msgspec.msgpack.Encoder()
    decode_ns, json_ns, admit_ns, instructions, cycles = [], [], [], [], []
    for index in range(1, samples + 1):
        t_ms = index * 4.0
        core.step(ObservationEvent(t=round(t_ms * MS), observation_id=f"O{index}"))
        fields = _fields(index, t_ms, start, fast)
        chunk = decode_event_chunk(fields, round(t_ms * MS))
        frame = encoder.encode(to_wire(chunk))
        text = json.dumps(fields)
        t = round((t_ms + 1) * MS)
        json_ns.append(_timed(lambda text=text: json.loads(text)))
        decode_ns.append(_timed(lambda frame=frame, t=t: decode_wire_chunk(frame, t)))
        counts = counters.read() if counters else (0, 0)
        began = time.perf_counter_ns()
        decoded = decode_wire_chunk(frame, t)
        lines = _admit(core, ChunkEvent(t, decoded))
        admit_ns.append(time.perf_counter_ns() - began)
        if counters:
            after = counters.read()
            instructions.append(after[0] - counts[0])
            cycles.append(after[1] - counts[1])
        if index < 5 and lines[0].decision not in ("accepted", "replaced"):
            raise RuntimeError(f"benchmark chunk was refused: {lines[0]}")
        core.step(TickEvent(t=t))
    figures = {"decode": _percentiles(decode_ns), "json": _percentiles(json_ns),
               "admit": _percentiles(admit_ns)}
    if counters:  # thousands, so that _percentiles' /1e3 leaves them in thousands
        figures["instructions"] = _percentiles(instructions)
        figures["cycles"] = _percentiles(cycles)
    return figures


def _admit(core: Core, event: Event) -> tuple[Line, ...]:
    """Every line an event leads to, running any job the core asks for at once (the cost of
    the whole admission, wherever a live run would run its long part)."""
    step = core.step(event)
    lines = step.lines
    for effect in step.effects:
        if isinstance(effect, Compute):
            config = core.config
            result = run_job(effect.job, config.limits, config.cartesian,
                             config.collision)
            lines += _admit(core, ComputedEvent(t=event.t, result=result))
    return lines


def _geometry_cost(samples: int) -> dict[str, tuple[float, float]]:
    """50x7 feasible chunks, with and without the cell's geometry, interleaved: the core's
    steps (on the loop) and the clearance job (in the worker on a live run), apart."""
    cores = {with_geometry: Core(_config(7, with_geometry)) for with_geometry in (False, True)}
    loop: dict[bool, list[int]] = {False: [], True: []}
    job: list[int] = []
    for index in range(1, samples + 1):
        t_ms = index * 4.0
        t = round((t_ms + 1) * MS)
        for with_geometry, core in cores.items():
            core.step(ObservationEvent(t=round(t_ms * MS), observation_id=f"O{index}"))
            fields = _fields(index, t_ms, core.config.initial_q.copy(), fast=False)
            frame = msgspec.msgpack.Encoder().encode(to_wire(decode_event_chunk(
                fields, round(t_ms * MS))))
            began = time.perf_counter_ns()
            step = core.step(ChunkEvent(t, decode_wire_chunk(frame, t)))
            spent = time.perf_counter_ns() - began
            for effect in step.effects:
                if isinstance(effect, Compute):
                    config = core.config
                    began = time.perf_counter_ns()
                    result = run_job(effect.job, config.limits, config.cartesian,
                                     config.collision)
                    job.append(time.perf_counter_ns() - began)
                    began = time.perf_counter_ns()
                    step = core.step(ComputedEvent(t=t, result=result))
                    spent += time.perf_counter_ns() - began
            decided = [line for line in step.lines if getattr(line, "decision", None)]
            if index < 5 and decided[0].decision not in ("accepted", "replaced"):
                raise RuntimeError(f"benchmark chunk was refused: {decided[0]}")
            loop[with_geometry].append(spent)
            core.step(TickEvent(t=t))
    return {"plain": _percentiles(loop[False]), "loop": _percentiles(loop[True]),
            "job": _percentiles(job)}


def _timed(fn: Callable[[], object]) -> int:
    began = time.perf_counter_ns()
    fn()
    return time.perf_counter_ns() - began


def _replay_scenario(seconds: int) -> Scenario:
    config = _config(6)
    events: list = []
    start = config.initial_q.copy()
    for k in range(seconds * 100):  # a state every 10 ms
        t_ms = k * 10
        events.append(StateEvent(t=t_ms * MS, q=tuple(start.tolist())))
        if k % 10 == 0:  # an observation and a chunk every 100 ms
            index = k // 10 + 1
            events.append(ObservationEvent(t=t_ms * MS, observation_id=f"O{index}"))
            fields = _fields(index, t_ms, start, fast=False)
            fields["first_action_time"] = t_ms + 30
            arrival = (t_ms + 30) * MS
            events.append(ChunkEvent(arrival, decode_event_chunk(fields, arrival)))
    events.sort(key=lambda e: e.t)
    return Scenario("bench", "bench", config, events, seconds * 1000 * MS, False)


def _replay_speed(seconds: int) -> tuple[float, float, int]:
    scenario = _replay_scenario(seconds)
    timeline = list(scenario.timeline())
    ticks = sum(isinstance(e, TickEvent) for e in timeline)
    core = Core(scenario.config)
    began = time.perf_counter()
    for event in timeline:
        _admit(core, event)
    core_only = time.perf_counter() - began
    core = Core(scenario.config)
    began = time.perf_counter()
    for event in timeline:
        for line in _admit(core, event):
            encode(line)
    with_log = time.perf_counter() - began
    return seconds / core_only, seconds / with_log, ticks


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=3000)
    parser.add_argument("--seconds", type=int, default=60)
    args = parser.parse_args()
    gc.disable()
    counters = open_counters()
    print(f"admission cost, {args.samples} chunks each (us, p50 / p99)")
    for dim in (6, 7):
        smooth = _admission(dim, args.samples, fast=False, counters=counters)
        fast = _admission(dim, args.samples, fast=True)
        print(f"  50x{dim}  wire decode only      {smooth['decode'][0]:7.1f} / "
              f"{smooth['decode'][1]:7.1f}")
        print(f"  50x{dim}  stdlib json parse     {smooth['json'][0]:7.1f} / "
              f"{smooth['json'][1]:7.1f}   (baseline: parsing alone, no decision)")
        print(f"  50x{dim}  full admission        {smooth['admit'][0]:7.1f} / "
              f"{smooth['admit'][1]:7.1f}   (feasible chunk)")
        print(f"  50x{dim}  full admission        {fast['admit'][0]:7.1f} / "
              f"{fast['admit'][1]:7.1f}   (needs exact projection)")
        ratio = smooth["admit"][1] / smooth["json"][1]
        print(f"  50x{dim}  admission p99 / json-parse p99 = {ratio:.2f}")
        if "instructions" in smooth:
            print(f"  50x{dim}  full admission, user space: {smooth['instructions'][0]:.0f}k "
                  f"instructions p50, {smooth['cycles'][0]:.0f}k / {smooth['cycles'][1]:.0f}k "
                  "cycles p50 / p99")
        else:
            print(f"  50x{dim}  instruction counts: not available (no perf events here)")
    geometry = _geometry_cost(min(args.samples, 600))
    print("  50x7  with [geometry] (the shipped cell's), in the same run:")
    print(f"  50x7  admission on the loop, no geometry    {geometry['plain'][0]:7.1f} / "
          f"{geometry['plain'][1]:7.1f}")
    print(f"  50x7  admission on the loop, with geometry  {geometry['loop'][0]:7.1f} / "
          f"{geometry['loop'][1]:7.1f}   (both steps: the chunk, its job's result)")
    print(f"  50x7  clearance job (the worker's part)     {geometry['job'][0]:7.1f} / "
          f"{geometry['job'][1]:7.1f}")
    gc.enable()
    core_x, log_x, ticks = _replay_speed(args.seconds)
    print(f"replay of a {args.seconds} s scenario ({ticks} ticks at 2 ms, chunks at 10 Hz): "
          f"{core_x:.0f}x real time (core), {log_x:.0f}x with JSON log encoding")


if __name__ == "__main__":
    main()
