"""The whole cell through every vendor driver and its emulator.

Each driver runs the assembly cycle through its real library over its real transport; then
each emulated device fault (the UR refusing servoJ in protective stop, a Dynamixel servo's
hardware error status, a CiA 402 drive in FAULT after an EMCY or silent), injected while the
policy is streaming, must reach the core as a journaled controller event with the driver's
reason, put the fallback machine in the right state, and leave the arm held.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from assurance.reasons import ReasonCode
from kernel.app.live import run_live
from kernel.app.session import RunContext
from kernel.shell.loop import run
from tests.cell.harness import (
    DRIVER_MANIFESTS,
    DriverCycle,
    manifest,
    replays_identically,
    run_dir,
)

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("name", DRIVER_MANIFESTS)
def test_a_full_cycle_runs_through_the_driver(
        name: str, driver_cycle: Callable[[str], DriverCycle]) -> None:
    """As a real cell would: VERIFY judges on measured evidence alone (the simulator's ground
    truth switched off). The run is tests/cell/conftest.py's, which test_loopback.py reads
    too."""
    summary, directory, _ = driver_cycle(name)
    assert summary["cycles"]["attempted"] == 1
    assert summary["cycles"]["verified"] == 1  # the driver's gripper grasped the peg
    reason = summary["cycles"]["detail"][0]["reason"]
    assert reason.startswith("inserted: measured") and "ground truth" not in reason
    assert summary["driver"]["faults"] == "none"
    assert summary["link"]["chunks_admitted"] > 5
    assert replays_identically(directory)


class FaultAfterApproach:
    """Injects ``fault`` once the policy streams pre-contact chunks; once the runtime has left
    RUNNING, samples the emulated arm's joints twice (is it held?) and ends the run."""

    def __init__(self, fault: str, fields: dict[str, Any], give_up_s: float = 4.0) -> None:
        self.fault, self.fields, self.give_up_s = fault, fields, give_up_s
        self.injected_ns: int | None = None
        self.fallback_ns: int | None = None
        self.q_after: list[np.ndarray] = []

    def __call__(self, context: RunContext) -> bool:
        cell = context.cell
        now = cell.gateway.now_ns()
        if self.injected_ns is None:
            if cell.controller.runner.step == "pre-contact" and (
                    cell.core.inspect_state().queue.pending_rows(now) > 0):
                cell.world.inject(self.fault, **self.fields)
                self.injected_ns = now
            return False
        if self.fallback_ns is None:
            if cell.core.status().mode != "RUNNING":
                self.fallback_ns = now
            return (now - self.injected_ns) * 1e-9 > self.give_up_s
        since = (now - self.fallback_ns) * 1e-9
        if since > 0.2 + 0.3 * len(self.q_after) and len(self.q_after) < 2:
            self.q_after.append(np.array(cell.world.inject("ground_truth")["q"]))
        return len(self.q_after) == 2


FAULTS = [
    ("sim-ur5e-rtde.toml", "protective_stop", {}, "CONTROLLER_FAULT", "CONTROLLER_STOP"),
    ("sim-ur5e-rtde.toml", "estop", {}, "E_STOP", "E_STOP"),
    ("sim-dynamixel.toml", "hardware_error", {"id": 3, "bit": "overload"}, "CONTROLLER_FAULT",
     "CONTROLLER_STOP"),
    ("sim-canopen.toml", "emcy", {"node": 2}, "CONTROLLER_FAULT", "CONTROLLER_STOP"),
    ("sim-canopen.toml", "heartbeat_stop", {"node": 4}, "CONTROLLER_FAULT", "CONTROLLER_STOP"),
]


@pytest.mark.parametrize(("name", "fault", "fields", "trigger", "mode"), FAULTS,
                         ids=[f"{f[0].split('.')[0]}-{f[1]}" for f in FAULTS])
def test_a_device_fault_reaches_the_right_fallback_and_the_arm_holds(
    tmp_path: Path, name: str, fault: str, fields: dict[str, Any], trigger: str, mode: str
) -> None:
    hook = FaultAfterApproach(fault, fields)
    summary = run(run_live(manifest(name, cycles=1), tmp_path, hook=hook))
    assert hook.injected_ns is not None, "the fault was never injected"
    assert hook.fallback_ns is not None, "the runtime never left RUNNING"
    transitions = [t for t in summary["fallback_transitions"] if t["t"] * 1e6 >= hook.injected_ns]
    assert transitions and transitions[0]["to"] == mode and transitions[0]["trigger"] == trigger
    assert summary["driver"]["faults"] != "none"
    lines = [json.loads(line) for line in (run_dir(tmp_path) / "decisions.jsonl").open()]
    after = [line for line in lines if line["kind"] == "tick"
             and line["t"] >= transitions[0]["t"]]
    assert after and all(line["command"] == "stop" and line["mode"] == mode for line in after)
    assert len(hook.q_after) == 2
    assert np.abs(hook.q_after[1] - hook.q_after[0]).max() < 2e-3  # held still
    journal = [json.loads(line) for line in (run_dir(tmp_path) / "journal.jsonl").open()]
    reported = [e for e in journal if e.get("kind") == "controller"]
    assert reported and reported[0]["status"] in ("fault", "estop", "reject")
    assert reported[0].get("reason") in ReasonCode.__members__  # the driver's own, journaled
    stops = [e for e in journal if e.get("kind") == "command" and e["t"] >= transitions[0]["t"]]
    assert stops and all(e["effect"]["effect"] == "stop" for e in stops)
    assert replays_identically(run_dir(tmp_path))
