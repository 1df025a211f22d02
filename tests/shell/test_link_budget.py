"""The policy link's budgets on a clock the test moves: rates, requests in flight, and where in
the control period an admission may run."""

from __future__ import annotations

import asyncio

import pytest

from kernel.shell.link_budget import AdmissionPacer
from kernel.shell.link_protocol_budget import RequestWindow, TokenBucket

MS = 1_000_000


def test_a_bucket_passes_one_burst_then_its_rate() -> None:
    bucket = TokenBucket(100.0)
    assert bucket.burst == 10
    assert sum(bucket.take(0) for _ in range(50)) == 10  # the burst, however many arrive
    assert sum(bucket.take(50 * MS) for _ in range(50)) == 5  # 100/s for 50 ms
    assert sum(bucket.take(10_050 * MS) for _ in range(50)) == 10  # never more than a burst


@pytest.mark.parametrize("rate", [0.0, -1.0, float("nan")])
def test_a_rate_limit_must_be_positive(rate: float) -> None:
    with pytest.raises(ValueError):
        TokenBucket(rate)


def test_the_window_holds_at_most_its_limit_until_answers_or_expiry() -> None:
    window = RequestWindow(2, 250 * MS)
    window.sent("o1", 0)
    window.sent("o2", 100 * MS)
    assert not window.open(100 * MS) and window.deadline() == 250 * MS
    window.answered("o2")
    assert window.open(100 * MS)
    window.sent("o3", 100 * MS)
    assert window.open(250 * MS) and window.expired == 1 and len(window) == 1  # o1 expired


def test_only_the_first_chunk_citing_a_request_is_its_expected_answer() -> None:
    window = RequestWindow(4, 1000 * MS)
    window.sent("o1", 0)
    assert window.claim("o1") and not window.claim("o1")
    assert not window.claim("never-sent")
    window.answered("o1")
    assert not window.claim("o1")  # answered: a later chunk citing it is no answer


def test_an_unreadable_answer_frees_the_oldest_request() -> None:
    window = RequestWindow(2, 1000 * MS)
    window.sent("o1", 0)
    window.sent("o2", 1)
    window.answered(None)
    assert window.claim("o2") and not window.claim("o1")
    window.clear()
    assert len(window) == 0 and window.open(2) and window.deadline() is None


async def test_admissions_start_only_early_enough_in_the_period() -> None:
    now = [0]
    pacer = AdmissionPacer(per_period=2, reserve_ns=1_000_000, clock=lambda: now[0])
    pacer.period_done(next_deadline_ns=2_000_000)
    await pacer.slot()  # t = 0: at once
    now[0] = 500_000
    await pacer.slot()  # still inside the window, second of two
    assert pacer.deferred == 0
    third = asyncio.create_task(pacer.slot())
    await asyncio.sleep(0)
    assert not third.done()  # the period's two are used: waits for the next tick
    now[0] = 1_200_000
    late = asyncio.create_task(pacer.slot())
    await asyncio.sleep(0)
    assert not late.done()  # too close to the deadline, even with none used
    pacer.period_done(next_deadline_ns=4_000_000)
    now[0] = 3_500_000  # the tick ran long: the waiting ones still run right after it
    await asyncio.wait_for(asyncio.gather(third, late), 1.0)
    assert pacer.deferred == 2
    fourth = asyncio.create_task(pacer.slot())
    await asyncio.sleep(0)
    assert not fourth.done()  # both slots of this period went to the waiting ones
    pacer.period_done(next_deadline_ns=6_000_000)
    await asyncio.wait_for(fourth, 1.0)
