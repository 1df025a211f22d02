"""A stalled control loop is a fault the core decides (issue 15, item 4).

A tick reads a fresh sample before the core decides, so after a stall the state watchdog sees a
young sample and never fired: a run with 4 s without a tick reported nothing. The core now
measures the gap between tick times (which the journal records, so a replay sees the same gap):
a gap past the state watchdog is WATCHDOG, with the gap in the transition's detail.
"""

from __future__ import annotations

from kernel.core.events import StateEvent
from kernel.core.lines import TransitionLine
from kernel.core.runtime import Core
from tests.runtime.machine_setup import PERIOD_MS, core_config, feed, tick

MS = 1_000_000
TIMEOUT_MS = 50


def _fresh_tick(core: Core, t_ns: int) -> list[TransitionLine]:
    """A sample read at the tick's own instant, then the tick: what the live loop does."""
    q = tuple(core.config.initial_q[:6].tolist())
    lines = feed(core, StateEvent(t=t_ns, q=q))
    lines += tick(core, t_ns)[1]
    return [line for line in lines if isinstance(line, TransitionLine)]


def _ticks_until(core: Core, end_ms: int) -> list[TransitionLine]:
    transitions = []
    for t_ms in range(0, end_ms + 1, PERIOD_MS):
        transitions += _fresh_tick(core, t_ms * MS)
    return transitions


def test_a_gap_between_ticks_past_the_state_watchdog_is_a_watchdog_fault() -> None:
    core = Core(core_config("FREE_SPACE", state_timeout_ms=TIMEOUT_MS))
    assert _ticks_until(core, 100) == []
    stalled_ms = 100 + 4002  # the robot PC's journal: 4002 ms without a tick
    (transition,) = _fresh_tick(core, stalled_ms * MS)
    assert transition.trigger == "WATCHDOG" and transition.to == "CONTROLLER_STOP"
    assert transition.t == stalled_ms
    assert transition.detail is not None and "4002 ms" in transition.detail
    assert str(core.status().mode) == "CONTROLLER_STOP"


def test_a_gap_within_the_state_watchdog_is_not_a_fault() -> None:
    core = Core(core_config("FREE_SPACE", state_timeout_ms=TIMEOUT_MS))
    assert _ticks_until(core, 100) == []
    assert _fresh_tick(core, (100 + TIMEOUT_MS) * MS) == []  # exactly the watchdog: late, kept
    assert str(core.status().mode) == "RUNNING"


def test_without_a_state_watchdog_a_gap_decides_nothing() -> None:
    core = Core(core_config("FREE_SPACE"))
    assert _ticks_until(core, 20) == []
    assert _fresh_tick(core, 5_000 * MS) == []
