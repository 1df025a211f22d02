"""Clock sync over the wire: the server's deliberately foreign clock is measured, not assumed."""

from __future__ import annotations

from kernel.core.events import ClockSyncEvent, HandshakeEvent
from kernel.wire import SERVER_CLOCK_DOMAIN
from tests.wire.harness import CLOCK_OFFSET_NS, running, server_config, wait_for


async def test_offset_recovered_within_the_round_trip_bound() -> None:
    async with running() as link:
        await wait_for(lambda: link.gateway.handshakes(), "a clock sync and a handshake")
        events = list(link.gateway.events)
        syncs = [e for e in events if isinstance(e, ClockSyncEvent)]
    (sync, *_) = syncs
    assert sync.domain == SERVER_CLOCK_DOMAIN
    # The server's clock is ours + CLOCK_OFFSET_NS (plus the gateway's origin shift), so
    # t_client = t_server + offset with offset = -(CLOCK_OFFSET_NS + origin).
    true_offset = -(CLOCK_OFFSET_NS + link.gateway.origin_ns)
    assert sync.round_trip >= 0
    assert abs(sync.offset - true_offset) <= sync.round_trip // 2 + 1
    # fed before the handshake, so the first chunk already has a valid clock
    first_handshake = next(i for i, e in enumerate(events) if isinstance(e, HandshakeEvent))
    assert events.index(sync) < first_handshake


async def test_clock_is_refreshed_periodically() -> None:
    async with running(clock_refresh_s=0.05) as link:
        await wait_for(lambda: link.client.counters.clock_syncs >= 3, "three clock syncs")
        await wait_for(lambda: link.gateway.admitted(), "an admitted chunk")
    assert link.client.counters.clock_round_trips >= 15
    assert link.gateway.refused_with("CLOCK_INVALID") == []


async def test_large_offset_still_admits_chunks_stamped_in_server_time() -> None:
    offset = -3_600 * 10**9  # the server's clock reads an hour behind
    async with running(server_config(clock_offset_ns=offset)) as link:
        await wait_for(lambda: len(link.gateway.admitted()) >= 3, "three admitted chunks")
    assert link.gateway.refused_with("CLOCK_INVALID") == []
    assert link.gateway.refused_with("EXPIRED") == []
