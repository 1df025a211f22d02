"""Every server fault ends as the right refusal in the core's log, or as a clean close."""

from __future__ import annotations

import pytest

from assurance.reasons import ReasonCode as R
from stubs.policy_server import FaultConfig
from tests.wire.harness import running, server_config, wait_for

# fault → the reason it must produce; "survives" when the connection must stay up through it
CONTENT_FAULTS = [
    (FaultConfig(garbage=0.5), R.MALFORMED, True),
    (FaultConfig(nonfinite=0.5), R.NONFINITE, True),
    (FaultConfig(duplicate=1.0), R.DUPLICATE, True),
    (FaultConfig(reorder=0.5), R.REORDERED, True),
    (FaultConfig(wrong_dim=1.0), R.SCHEMA_MISMATCH, False),
    (FaultConfig(checkpoint="act-insert-2026-06"), R.CHECKPOINT_NOT_ALLOWED, False),
]


@pytest.mark.parametrize(("faults", "reason", "survives"), CONTENT_FAULTS,
                         ids=[reason for _, reason, _ in CONTENT_FAULTS])
async def test_content_fault_becomes_a_refusal(
    faults: FaultConfig, reason: R, survives: bool
) -> None:
    async with running(server_config(faults=faults)) as link:
        gateway = link.gateway
        await wait_for(lambda: len(gateway.refused_with(reason)) >= 2, f"two {reason} lines")
        if survives:
            await wait_for(lambda: len(gateway.admitted()) >= 3, "chunks admitted between")
        else:
            await wait_for(lambda: link.client.counters.reconnects >= 1, "a reconnection")
        counters = link.client.counters
        downs = len(gateway.link_events("down"))
    refused = gateway.refused_with(reason)[0]
    assert refused.decision in ("rejected", "ignored") and refused.chunk_id
    assert counters.protocol_violations == 0 and counters.oversized == 0
    if survives:
        assert counters.connects == 1 and downs == 0
    else:
        # a compatibility refusal ends the session in the core (DEGRADED): the client closes
        # cleanly and comes back through a new handshake
        assert "session_ended" in link.server.stats.byes_received
        assert len(gateway.handshakes()) >= 2


async def test_malformed_chunk_is_counted_and_named() -> None:
    async with running(server_config(faults=FaultConfig(garbage=1 / 3))) as link:
        await wait_for(lambda: link.client.counters.malformed >= 2, "two malformed chunks")
    line = link.gateway.refused_with(R.MALFORMED)[0]
    assert line.reasons == (R.MALFORMED,)
    assert line.detail and "byte length" in line.detail


async def test_dropped_and_delayed_chunks_leave_the_link_up() -> None:
    faults = FaultConfig(drop=0.5, spike=0.25, spike_ms=30.0)
    async with running(server_config(faults=faults)) as link:
        await wait_for(lambda: len(link.gateway.admitted()) >= 4, "four admitted chunks")
        stats, counters = link.server.stats, link.client.counters
    assert stats.chunks_dropped >= 1
    assert counters.chunks_in <= stats.chunks_produced - stats.chunks_dropped
    assert counters.connects == 1


PROTOCOL_FAULTS = [
    (FaultConfig(garbage_frame_after=2), "protocol_violations", "protocol_violation"),
    (FaultConfig(unknown_type_after=2), "protocol_violations", "protocol_violation"),
    (FaultConfig(oversized_after=2), "oversized", None),
    (FaultConfig(stall_after=2), "link_timeouts", None),  # a stalled server reads nothing
]


@pytest.mark.parametrize(("faults", "counter", "bye"), PROTOCOL_FAULTS,
                         ids=["garbage_frame", "unknown_type", "oversized", "stall"])
async def test_protocol_fault_closes_cleanly_and_reconnects(
    faults: FaultConfig, counter: str, bye: str | None
) -> None:
    # The silence must be declared before the core escalates the underrun it causes
    # (FREE_SPACE: 200 ms) to SAFE_HOLD, which only an operator may end.
    async with running(server_config(faults=faults), heartbeat_timeout_ms=200.0) as link:
        counters = link.client.counters
        await wait_for(lambda: getattr(counters, counter) >= 1, counter)
        await wait_for(lambda: counters.handshakes_accepted >= 2, "a second session")
        await wait_for(lambda: len(link.gateway.admitted()) >= 4, "chunks after reconnecting")
        byes = list(link.server.stats.byes_received)
        byes_sent = counters.byes_sent  # before the shutdown bye at the end of the test
    assert getattr(counters, counter) == 1  # the fault hit the first connection only
    assert link.gateway.link_events("down"), "LinkEvent(down) was fed"
    if bye is not None:
        assert byes[0] == bye
    if counter != "oversized":  # after a 1009 close the transport is gone: nothing to say
        assert byes_sent >= 1
    assert link.gateway.refused_with(R.MALFORMED) == []
    epochs = [h.queue_epoch for h in link.gateway.handshakes()]
    assert epochs == sorted(set(epochs)), "every new session has a newer epoch"
