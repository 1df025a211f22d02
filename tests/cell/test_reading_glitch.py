"""A reading glitch never moves the arm: each vendor driver's cell, glitches in every phase.

Each run is one whole cell through the vendor's driver and its emulator; the emulator reports
one joint 0.5 rad off (the plant does not move by it) for one sample, 6 ms or 200 ms, once in
each phase the cycle passes through: the transport move (FREE_SPACE, the planner's), the
policy's pre-contact stream, the insertion (CONTACT), and a SAFE_HOLD. The durations rotate
over the drivers so that every phase gets each of them once and every driver all three.

Asserted for every glitch: a glitched sample that reached the core while it was not already
holding raised STATE_IMPLAUSIBLE at that very sample; and whenever the glitch reached a core
that held (the glitch caused the hold, or came during one), the plant's true joints never went
further from where they were last commanded before the hold than they were from their
command at the onset (the servo's lag) or than braking takes: the distance computed here,
from the journaled commands' velocity and acceleration and the manifest's acceleration and
jerk limits (step by step, not with warden's code), plus the reaction time (the hold goes
out the tick after the one that read the glitch) and the servo's overshoot. Measured from
the last command rather than from the true joint at the onset, the bound also holds when
a loaded machine runs the emulator's physics slower than the wall clock and the arm trails
its commands. The command's velocity and acceleration are per control period: warden's
motion advances one period a tick, however late the tick; taken over the journal's wall time
on a loaded host they were a fraction of the path's, the cause of this campaign's failures
at load 4-9. Before the plausibility check the 200 ms glitch in pre-contact drove the arm
0.5 rad.

On the shared 2-core test host a vendor cell is sometimes kept from a phase by the load (a
stalled loop or the device's watchdog stops it, or the cycle's time runs out in holds): the
glitches it never injected are skipped, by name and with why, after every glitch it did
inject has been checked; one injected and never over fails. The lockstep campaign must
exercise them all.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from kernel.app.live import run_live
from kernel.shell.loop import run
from tests.cell.glitches import (
    CONTACT,
    HOLD,
    PRE_CONTACT,
    TRANSPORT,
    Glitch,
    GlitchCampaign,
    braking_distance,
    last_command,
    motion_from,
)
from tests.cell.harness import manifest, replays_identically, run_dir

pytestmark = pytest.mark.slow

ONE, SIX_MS, LONG = {"samples": 1}, {"duration_ms": 6}, {"duration_ms": 200}
PLANS = {
    "sim-ur5e-rtde.toml": {TRANSPORT: LONG, HOLD: SIX_MS, PRE_CONTACT: SIX_MS, CONTACT: ONE},
    "sim-dynamixel.toml": {TRANSPORT: SIX_MS, HOLD: LONG, PRE_CONTACT: ONE, CONTACT: LONG},
    "sim-canopen.toml": {TRANSPORT: ONE, HOLD: ONE, PRE_CONTACT: LONG, CONTACT: SIX_MS},
}
TRACKING_RAD = 0.02
"""What the plant may overshoot a command by (its servo loop, the MuJoCo contact with the
part)."""


@pytest.mark.parametrize("name", list(PLANS))
def test_a_reading_glitch_never_moves_the_arm(tmp_path: Path, name: str,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RUNTIME_DIRECTORY", str(tmp_path))  # the operator socket: ours alone
    glitches = [Glitch(phase, spec, joint=index % 2) for index, (phase, spec)
                in enumerate(PLANS[name].items())]
    cell = manifest(name, cycles=1)
    campaign = GlitchCampaign(glitches)
    journals = tmp_path / "journals"
    journals.mkdir()
    run(run_live(cell, journals, hook=campaign))
    _check(glitches, cell, run_dir(journals))


def _check(glitches: list[Glitch], cell: Any, directory: Path,
           every_sample_seen: bool = False) -> None:
    """The campaign's assertions (the module docstring); ``every_sample_seen``: each glitch
    must have reached the core (a virtual clock reads every sample)."""
    decisions = [json.loads(line) for line in (directory / "decisions.jsonl").open()]
    states = [e for e in map(json.loads, (directory / "journal.jsonl").open())
              if e.get("kind") == "state"]
    period_s = cell.core.control_period_ns * 1e-9
    limits, jerk = cell.core.limits, cell.core.motion.interpolator_jerk
    journal = [json.loads(line) for line in (directory / "journal.jsonl").open()]
    # The hold a glitch caused: the last command before it, and how far from it braking takes
    # the arm (a later glitch in that hold is held to the same).
    hold: tuple[np.ndarray, np.ndarray] | None = None
    for glitch in sorted((g for g in glitches if g.injected_ns is not None),
                         key=lambda g: g.injected_ns or 0):
        seen = _first_glitched_sample(glitch, states)
        assert seen is not None or not every_sample_seen, f"{glitch.label}: never read"
        in_hold = glitch.modes[0] == "SAFE_HOLD"
        caused = False
        if seen is not None and not in_hold:
            caused = any(d["kind"] == "transition" and d.get("trigger") == "STATE_IMPLAUSIBLE"
                         and d["t"] == seen for d in decisions)
            assert caused, f"{glitch.label}: a glitched sample at {seen} ms went unnoticed"
        if caused:
            hold = _braking_bound(glitch, seen, journal, period_s, limits, jerk)
        elif not in_hold or hold is None:
            hold = None
            continue  # never reached the core (the arm went on as commanded), or a hold
            # that something else began
        where, bound = hold
        moved = motion_from(glitch, where)
        assert np.all(moved <= bound), (
            f"{glitch.label}: the true arm went {np.round(moved, 4).tolist()} rad from the last "
            f"command before the hold, braking allows {np.round(bound, 4).tolist()}")
    assert replays_identically(directory)
    open_ = [g.label for g in glitches if g.injected_ns is not None and g.closed_ns is None]
    assert open_ == [], f"injected and never over: {open_}"
    missing = [g.label for g in glitches if g.injected_ns is None]
    assert not (missing and every_sample_seen), f"never injected: {missing}"
    if missing:
        pytest.skip(f"not exercised: {missing}, the cell never got there "
                    f"({_run_end(decisions, directory)}); every glitch injected held")


def _run_end(decisions: list[dict[str, Any]], directory: Path) -> str:
    """What kept a vendor cell from the phases left: on the loaded 2-core test host, a stop
    the load causes (a stalled loop, the device's watchdog on a silent warden), or the
    cycle's time running out in holds."""
    stops = [f"{d['trigger']} at {d['t']:.0f} ms{': ' + d['detail'] if 'detail' in d else ''}"
             for d in decisions if d["kind"] == "transition" and d.get("machine") == "fallback"
             and d.get("to") == "CONTROLLER_STOP"]
    if stops:
        return stops[0]
    summary = directory / "summary.json"
    cycles = json.loads(summary.read_text())["cycles"]["detail"] if summary.exists() else []
    return next((c["reason"] for c in cycles if not c["verified"]), "the run ended")


def _braking_bound(glitch: Glitch, seen_ms: float, journal: list[dict[str, Any]],
                   period_s: float, limits: Any, jerk: float) -> tuple[np.ndarray, np.ndarray]:
    """Where the arm was last commanded before the hold the glitch caused, and how far from
    there it may go: its lag behind the command at the onset, or what braking the command
    takes (from the commands' velocity and acceleration, the reaction time, the limits),
    plus overshoot. Before the hold, not before the onset: on a loaded host the first
    glitched sample can reach the core ticks after the injection, and the arm goes on as
    commanded meanwhile (a policy's pre-contact rows moved a CiA 402 arm 0.02 rad so)."""
    assert glitch.injected_ns is not None and glitch.q0 is not None
    at_onset = last_command(journal, glitch.injected_ns * 1e-6, period_s)
    # The tick that read the glitched sample commands the hold: the command before it.
    last = last_command(journal, seen_ms - 1e-3, period_s)
    assert last is not None and at_onset is not None, f"{glitch.label}: no command before it"
    lag = np.abs(glitch.q0 - at_onset.q)
    brake = np.array([abs(v) * 3 * period_s + braking_distance(
        v, a, float(limits.acceleration[j]), jerk)
        for j, (v, a) in enumerate(zip(last.qd, last.qdd, strict=True))])
    return last.q, np.maximum(lag, brake) + TRACKING_RAD


def _first_glitched_sample(glitch: Glitch, states: list[dict[str, Any]]) -> float | None:
    """The time (ms) of the first state the core was fed with the glitch in it: the glitched
    joint jumps by more than half the offset from the sample before (no joint of these arms
    moves 0.25 rad in one period)."""
    if glitch.injected_ns is None or glitch.closed_ns is None:
        return None
    start, end = glitch.injected_ns * 1e-6, glitch.closed_ns * 1e-6
    previous = None
    for state in states:
        q = state["q"][glitch.joint]
        if previous is not None and start <= state["t"] <= end and (
                abs(q - previous) > glitch.offset / 2):
            return float(state["t"])
        previous = q
    return None


PERIOD_MS = 2  # sim-ur5e.toml
LOCKSTEP_PLANS = [
    {TRANSPORT: 1, HOLD: 3, PRE_CONTACT: 100, CONTACT: 3},
    {TRANSPORT: 3, HOLD: 100, PRE_CONTACT: 1, CONTACT: 100},
    {TRANSPORT: 100, HOLD: 1, PRE_CONTACT: 3, CONTACT: 1},
]
"""On the virtual clock a glitch is a number of the driver's samples, one a period: 1, 3
(6 ms) and 100 (200 ms); rotated as the vendor cells' are."""


@pytest.mark.parametrize("plan", LOCKSTEP_PLANS, ids=["a", "b", "c"])
def test_a_reading_glitch_never_moves_the_arm_in_lockstep(
        tmp_path: Path, plan: dict[str, int], monkeypatch: pytest.MonkeyPatch) -> None:
    """The same on the in-process plant and a virtual clock: every sample is read, so every
    glitch reaches the core, whatever the machine's load."""
    from kernel.app.lockstep import run_lockstep
    from kernel.manifest import ClockKind

    monkeypatch.setenv("RUNTIME_DIRECTORY", str(tmp_path))
    glitches = [Glitch(phase, {"samples": n}, joint=index % 2, lasts_s=n * PERIOD_MS * 1e-3)
                for index, (phase, n) in enumerate(plan.items())]
    cell = manifest("sim-ur5e.toml", cycles=1, clock=ClockKind.VIRTUAL)
    assert cell.core.control_period_ns == PERIOD_MS * 1_000_000
    journals = tmp_path / "journals"
    journals.mkdir()
    run(run_lockstep(cell, journals, hook=GlitchCampaign(glitches)))
    _check(glitches, cell, run_dir(journals), every_sample_seen=True)
