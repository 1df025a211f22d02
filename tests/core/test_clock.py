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
    expires_at,
    finite_ms,
    ms_to_ns,
    ns_to_ms,
    rows_due_before,
    slack,
    too_old,
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
# The contract's predicate, written out here as the oracle: an action executed at t_exec is too
# old when age + uncertainty > max_age, and late when its slack is negative.


def contract_too_old(t_exec: int, t_obs: int, max_age: int, uncertainty: int) -> bool:
    return age(t_exec, t_obs) + max(uncertainty, 0) > max_age


def test_age_and_slack_are_plain_differences() -> None:
    assert age(150, 100) == 50
    assert slack(100, 130) == -30


def test_the_boundary_instant_is_still_valid_one_ns_later_is_not() -> None:
    # observation at 100 ns, 100 ns allowed: age 100 runs, age 101 does not
    expiry = expires_at(t_obs=100, max_age=100, uncertainty=0)
    assert expiry == 201
    assert not too_old(200, expiry) and too_old(201, expiry)
    # 1 ns of uncertainty: age 99 + 1 == 100 runs, age 100 + 1 does not
    expiry = expires_at(100, 100, 1)
    assert not too_old(199, expiry) and too_old(200, expiry)


def test_a_negative_uncertainty_counts_as_none() -> None:
    assert expires_at(100, 100, -7) == expires_at(100, 100, 0)


@given(times, times, st.integers(0, 10**10), st.integers(-(10**9), 10**9))
def test_too_old_is_the_contract_predicate(
    t_exec: int, t_obs: int, max_age: int, uncertainty: int
) -> None:
    assert too_old(t_exec, expires_at(t_obs, max_age, uncertainty)) == contract_too_old(
        t_exec, t_obs, max_age, uncertainty)


@given(times, times, st.integers(0, 10**10), uncertainties, uncertainties)
def test_more_uncertainty_never_turns_an_expired_action_valid(
    t_exec: int, t_obs: int, max_age: int, u1: int, extra: int
) -> None:
    assert expires_at(t_obs, max_age, u1 + extra) <= expires_at(t_obs, max_age, u1)
    if too_old(t_exec, expires_at(t_obs, max_age, u1)):
        assert too_old(t_exec, expires_at(t_obs, max_age, u1 + extra))


@given(st.integers(-(10**6), 10**6), st.integers(1, 1000), st.integers(-(10**6), 10**6),
       st.integers(0, 60))
def test_rows_due_before_counts_each_row_with_a_deadline_before_the_instant(
    first_due: int, dt: int, instant: int, rows: int
) -> None:
    expected = sum(1 for j in range(rows) if first_due + j * dt < instant)
    assert rows_due_before(first_due, dt, instant, rows) == expected


def test_negative_slack_is_the_late_prefix_and_zero_slack_is_on_time() -> None:
    # rows due at 100, 110, 120, ... ns
    assert rows_due_before(100, 10, instant=100, rows=5) == 0  # ready exactly when row 0 is due
    assert rows_due_before(100, 10, 101, 5) == 1  # row 0's slack is −1 ns
    assert rows_due_before(100, 10, 120, 5) == 2
    assert rows_due_before(100, 10, 10**9, 5) == 5
    for ready in (100, 101, 120):
        late = [j for j in range(5) if slack(100 + j * 10, ready) < 0]
        assert rows_due_before(100, 10, ready, 5) == len(late)


def test_a_long_tail_outlives_the_bound_while_its_head_runs() -> None:
    """Observation at 0, 100 ms allowed, 2 ms of uncertainty, ten actions every 20 ms from
    40 ms: actions at 40, 60, 80 ms are young enough when due; 100 ms onwards are not."""
    ms = NS_PER_MS
    expiry = expires_at(0, 100 * ms, 2 * ms)
    assert expiry == 98 * ms + 1
    assert rows_due_before(40 * ms, 20 * ms, expiry, 10) == 3
    assert [too_old(40 * ms + j * 20 * ms, expiry) for j in range(5)] == [
        False, False, False, True, True]
    assert not too_old(98 * ms, expiry) and too_old(98 * ms + 1, expiry)


def test_an_old_observation_leaves_no_row_young_enough() -> None:
    ms = NS_PER_MS
    expiry = expires_at(-200 * ms, 100 * ms, 0)  # too old from −100 ms + 1 ns on
    assert rows_due_before(0, 10 * ms, expiry, 10) == 0


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
