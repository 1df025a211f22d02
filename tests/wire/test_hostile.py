"""Hostile peers: numbers out of any plausible range never raise out of the link task, and
nothing the core is fed stops a journal from replaying."""

from __future__ import annotations

import pytest

from kernel.core.events import ClockSyncEvent
from kernel.journal import event_record
from kernel.scenario.events import parse_events
from kernel.scenario.fields import Where
from kernel.wire import MAX_CLOCK_OFFSET_NS
from stubs.policy_server import FaultConfig
from tests.wire.harness import LoopbackGateway, running, server_config, wait_for


def journal_round_trip(gateway: LoopbackGateway) -> None:
    """Every event the core was fed becomes a journal line that parses back (the replay's
    first step): a value the journal cannot carry would make the run unreplayable."""
    records = [event_record(event) for event in gateway.events]
    parsed = parse_events(records, Where("journal", "events"), gateway.config.limits)
    assert len(parsed) == len(records)


@pytest.mark.parametrize("t_server", [2**64 - 1, -(2**63 - 1), 2**63 - 1],
                         ids=["beyond_int64", "int64_min", "int64_max"])
async def test_an_implausible_clock_pong_is_a_violation_never_a_crash(t_server: int) -> None:
    faults = FaultConfig(clock_t_server=t_server)
    async with running(server_config(faults=faults)) as link:
        counters = link.client.counters
        await wait_for(lambda: counters.protocol_violations >= 1, "a protocol violation")
        await wait_for(lambda: len(link.gateway.admitted()) >= 2, "a sane second session")
    assert counters.protocol_violations == 1  # the first connection only
    assert "protocol_violation" in link.server.stats.byes_received
    syncs = [e for e in link.gateway.events if isinstance(e, ClockSyncEvent)]
    assert syncs and all(abs(sync.offset) <= MAX_CLOCK_OFFSET_NS for sync in syncs)
    journal_round_trip(link.gateway)
