"""servoj's lookahead in the emulated controller: the client's 500 Hz stream aliases against the
controller's cycle (a cycle without a new target, then one with two). Followed raw, each such
beat is a stop and a double step the wrist feels as a jerk; smoothed over the lookahead, the
plant's target keeps the stream's speed to within one step over the window."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from stubs.ur_controller.script import ServoLookahead

CYCLE_S = 0.002
STEP = 1e-3  # rad per cycle: 0.5 rad/s


def _follow(lookahead: ServoLookahead, stream: list[float]) -> np.ndarray:
    return np.array([lookahead.smoothed([value] * 6)[0] for value in stream])


def _aliased_ramp(beats: list[int], cycles: int) -> list[float]:
    """What the controller reads per cycle from a ramp the client sends at the same nominal
    rate: the newest target, with a beat at each listed cycle (a repeat, then a double step)."""
    stream, index = [], 0
    for cycle in range(cycles):
        if cycle in beats:
            index -= 1  # no new target this cycle ...
        elif cycle - 1 in beats:
            index += 1  # ... two arrived by the next
        stream.append(index * STEP)
        index += 1
    return stream


@given(st.lists(st.integers(30, 170), max_size=6, unique=True).map(sorted))
def test_an_aliased_stream_keeps_its_speed_within_one_step_over_the_window(
        beats: list[int]) -> None:
    beats = [b for i, b in enumerate(beats) if i == 0 or b - beats[i - 1] > 1]
    lookahead = ServoLookahead(0.05, CYCLE_S)
    followed = _follow(lookahead, _aliased_ramp(beats, 200))
    speed = np.diff(followed[30:])  # once the window has filled with the ramp
    assert np.all(np.abs(speed - STEP) <= STEP / 25 + 1e-12)


def test_a_target_held_for_the_whole_window_is_reached_exactly() -> None:
    lookahead = ServoLookahead(0.05, CYCLE_S)
    followed = _follow(lookahead, [0.0] * 5 + [0.3] * 25)
    assert followed[-1] == pytest.approx(0.3, abs=1e-12)
    assert followed[5] == pytest.approx(0.3 / 25)


def test_the_lookahead_is_clamped_to_the_controllers_range() -> None:
    short, long = ServoLookahead(0.0, CYCLE_S), ServoLookahead(5.0, CYCLE_S)
    assert _follow(short, [0.0, 1.5])[-1] == pytest.approx(1.5 / 15)  # 0.03 s: 15 cycles
    assert _follow(long, [0.0, 1.0])[-1] == pytest.approx(1.0 / 100)  # 0.2 s: 100 cycles
