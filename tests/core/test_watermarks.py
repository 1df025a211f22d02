"""Low/high watermarks with hysteresis: when to request inference, and how often."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from assurance.watermarks import WatermarkConfig, Watermarks

MS = 1_000_000
CONFIG = WatermarkConfig(low_ns=100 * MS, high_ns=400 * MS, retry_ns=250 * MS,
                         margin_ns=10 * MS, window=20)


def marks() -> Watermarks:
    return Watermarks(CONFIG)


def test_requests_at_or_below_the_low_watermark() -> None:
    assert marks().should_request(0, 100 * MS, True)
    assert marks().should_request(0, 0, True)
    assert not marks().should_request(0, 100 * MS + 1, True)


def test_hysteresis_keeps_requesting_until_the_high_watermark() -> None:
    wm = marks()
    assert wm.should_request(0, 50 * MS, True)
    wm.answered()
    assert wm.should_request(10, 300 * MS, True)  # between: still in the requesting state
    wm.answered()
    assert not wm.should_request(20, 400 * MS, True)  # at high: stop
    assert not wm.requesting
    assert not wm.should_request(30, 300 * MS, True)  # between again: stay stopped


def test_one_request_in_flight_until_answered() -> None:
    wm = marks()
    assert wm.should_request(0, 50 * MS, True)
    assert not any(wm.should_request(t * MS, 50 * MS, True) for t in range(1, 250))
    wm.answered()
    assert wm.should_request(251 * MS - 1, 50 * MS, True)


def test_an_unanswered_request_is_repeated_after_the_retry_interval() -> None:
    wm = marks()
    assert wm.should_request(0, 50 * MS, True)
    assert not wm.should_request(250 * MS - 1, 50 * MS, True)
    assert wm.should_request(250 * MS, 50 * MS, True)
    assert not wm.should_request(260 * MS, 50 * MS, True)


@given(st.lists(st.tuples(st.integers(0, 20 * MS), st.integers(0, 500 * MS),
                          st.booleans()), max_size=40))
def test_never_a_request_storm(steps: list[tuple[int, int, bool]]) -> None:
    """Between answers, requests are at least retry_ns apart."""
    wm, t, last = marks(), 0, None
    for gap, depth, answer in steps:
        t += gap
        if wm.should_request(t, depth, True):
            assert last is None or t - last >= CONFIG.retry_ns
            last = t
        if answer:
            wm.answered()
            last = None


def test_not_allowed_resets_the_state() -> None:
    wm = marks()
    assert wm.should_request(0, 50 * MS, True)
    assert not wm.should_request(1, 50 * MS, False)
    assert not wm.requesting
    assert wm.should_request(2, 300 * MS, True) is False  # hysteresis state was cleared
    assert wm.should_request(3, 50 * MS, True)  # and so was the request in flight


def test_adaptive_low_watermark_follows_the_p95_round_trip() -> None:
    wm = Watermarks(WatermarkConfig(low_ns=100 * MS, high_ns=400 * MS, margin_ns=10 * MS,
                                    window=100))
    assert wm.p95_round_trip() is None and wm.low_ns == 100 * MS
    for _ in range(99):
        wm.record_round_trip(150 * MS)
    wm.record_round_trip(390 * MS)  # one outlier in a hundred is above the 95th percentile
    assert wm.p95_round_trip() == 150 * MS
    assert wm.low_ns == 160 * MS
    assert wm.should_request(0, 160 * MS, True)
    assert not Watermarks(CONFIG).should_request(0, 160 * MS, True)


def test_low_watermark_never_reaches_the_high_one_and_never_drops_below_config() -> None:
    wm = marks()
    wm.record_round_trip(10 * MS)
    assert wm.low_ns == 100 * MS
    wm.record_round_trip(10_000 * MS)
    assert wm.low_ns == 400 * MS - 1


def test_round_trip_window_and_negative_samples() -> None:
    wm = marks()
    wm.record_round_trip(-5)
    assert wm.p95_round_trip() is None
    wm.record_round_trip(300 * MS)
    for _ in range(CONFIG.window):
        wm.record_round_trip(1 * MS)
    assert wm.p95_round_trip() == 1 * MS  # the slow sample left the window


@given(st.lists(st.integers(0, 10**9), min_size=1, max_size=100))
def test_p95_is_a_sample_at_or_above_the_95th_percentile(samples: list[int]) -> None:
    wm = Watermarks(WatermarkConfig(window=128))
    for s in samples:
        wm.record_round_trip(s)
    p95 = wm.p95_round_trip()
    assert p95 in samples
    assert sum(s <= p95 for s in samples) >= 0.95 * len(samples)


@pytest.mark.parametrize("kw", [{"low_ns": 5, "high_ns": 5}, {"low_ns": -1},
                                {"retry_ns": 0}])
def test_invalid_configs_are_refused(kw: dict[str, int]) -> None:
    with pytest.raises(ValueError):
        WatermarkConfig(**kw)
