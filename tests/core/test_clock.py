"""Time arithmetic of the chunk contract (docs/contract.md §2): conversions, expiry, clocks."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from assurance.clock import (
    CLIENT_DOMAIN,
    NS_PER_MS,
    ClockInvalid,
    ClockMap,
    ClockSync,
    age,
    conservative_age,
    finite_ms,
    is_expired,
    ms_to_ns,
    ns_to_ms,
    slack,
)

times = st.integers(-(10**15), 10**15)
uncertainties = st.integers(0, 10**9)


# --- ms <-> ns -------------------------------------------------------------------------------


@given(st.integers(-(10**12), 10**12))
def test_whole_ms_convert_exactly_both_ways(ms: int) -> None:
    ns = ms_to_ns(ms)
    assert ns == ms * NS_PER_MS
    back = ns_to_ms(ns)
    assert back == ms
    assert type(back) is int


@pytest.mark.parametrize(
    ("ms", "ns"),
    [(0.5, 500_000), (12.25, 12_250_000), (0.001, 1_000), (0.1, 100_000), (-2.5, -2_500_000),
     (1e-6, 1), (33.333333, 33_333_333)],
)
def test_fractional_ms_round_to_nearest_ns(ms: float, ns: int) -> None:
    assert ms_to_ns(ms) == ns
    assert isinstance(ms_to_ns(ms), int)


@given(st.integers(-(10**15), 10**15))
def test_ns_survive_a_trip_through_fractional_ms(ns: int) -> None:
    ms = ns_to_ms(ns)
    assert ms_to_ns(ms) == ns
    if ns % NS_PER_MS:
        assert isinstance(ms, float)


# --- age, slack, expiry --------------------------------------------------------------------------


def test_age_and_slack_are_plain_differences() -> None:
    assert age(150, 100) == 50
    assert slack(100, 130) == -30
    assert conservative_age(150, 100, 7) == 57
    assert conservative_age(150, 100, -7) == 50  # a negative uncertainty never shortens age


@given(times, times, uncertainties, uncertainties)
def test_conservative_age_is_monotonic_in_uncertainty(
    t_exec: int, t_obs: int, u1: int, extra: int
) -> None:
    assert conservative_age(t_exec, t_obs, u1 + extra) >= conservative_age(t_exec, t_obs, u1)


@given(times, times, st.integers(0, 10**10), uncertainties, uncertainties, times, times)
def test_more_uncertainty_never_turns_an_expired_action_valid(
    t_exec: int, t_obs: int, max_age: int, u1: int, extra: int, deadline: int, ready: int
) -> None:
    if is_expired(t_exec, t_obs, max_age, u1, deadline, ready):
        assert is_expired(t_exec, t_obs, max_age, u1 + extra, deadline, ready)


@given(times, st.integers(1, 10**9), uncertainties)
def test_negative_slack_always_expires(deadline: int, late_by: int, u: int) -> None:
    # fresh observation, generous age bound: only the slack can expire it
    assert is_expired(deadline, deadline, 10**12, u, deadline, deadline + late_by)


def test_expiry_boundaries() -> None:
    # age + u == max_age is still valid; one ns more is expired
    assert not is_expired(t_exec=200, t_obs=100, max_age=100, uncertainty=0, t_deadline=200,
                          t_ready=200)
    assert is_expired(200, 100, 100, 1, 200, 200)
    assert is_expired(201, 100, 100, 0, 201, 201)
    # zero slack is on time
    assert not is_expired(100, 100, 100, 0, 150, 150)
    assert is_expired(100, 100, 100, 0, 150, 151)


# --- clock domains -------------------------------------------------------------------------------


def test_client_domain_needs_no_sync() -> None:
    assert ClockMap().translator(CLIENT_DOMAIN) == (0, 0)
    assert ClockMap(base_uncertainty_ns=40).translator(CLIENT_DOMAIN) == (0, 40)


def test_unknown_foreign_domain_is_clock_invalid() -> None:
    with pytest.raises(ClockInvalid):
        ClockMap().translator("server")
    synced = ClockMap().with_sync(ClockSync("gpu", 5, 10))
    with pytest.raises(ClockInvalid):
        synced.translator("server")


@given(st.integers(-(10**12), 10**12), st.integers(0, 10**9), st.integers(0, 10**6))
def test_a_sync_adds_half_the_round_trip_to_the_uncertainty(
    offset: int, round_trip: int, base: int
) -> None:
    clock = ClockMap(base_uncertainty_ns=base).with_sync(ClockSync("server", offset, round_trip))
    got_offset, uncertainty = clock.translator("server")
    assert got_offset == offset
    half = uncertainty - base
    assert 2 * half >= round_trip  # never less than half (odd round trips round up)
    assert 2 * half <= round_trip + 1


def test_a_new_sync_replaces_the_old_one_for_its_domain() -> None:
    clock = ClockMap().with_sync(ClockSync("server", 5, 10)).with_sync(ClockSync("server", 7, 2))
    assert clock.translator("server") == (7, 1)
    assert len(clock.syncs) == 1
    both = clock.with_sync(ClockSync("camera", -3, 4))
    assert both.translator("server") == (7, 1)
    assert both.translator("camera") == (-3, 2)


def test_finite_ms_accepts_only_real_finite_numbers() -> None:
    assert finite_ms(3) and finite_ms(2.5) and finite_ms(-1)
    for bad in (float("nan"), float("inf"), -float("inf"), True, "3", None):
        assert not finite_ms(bad)
