"""The handshake over the wire: only the core's ACCEPT opens a session."""

from __future__ import annotations

import msgspec
import structlog

from assurance.handshake import ClientHello
from assurance.reasons import ReasonCode as R
from stubs.policy_server import FaultConfig
from tests.wire.harness import LoopbackGateway, running, server_config, wait_for


async def test_accept_fingerprint_is_the_same_on_both_sides() -> None:
    async with running() as link:
        await wait_for(lambda: link.server.stats.fingerprints, "the server saw an ACCEPT")
        (verdict,) = link.gateway.handshakes()
        (decision,) = link.server.stats.decisions
    assert verdict.decision == "ACCEPT" and verdict.fingerprint
    assert decision.decision.decision == "ACCEPT"
    assert link.server.stats.fingerprints == [verdict.fingerprint] == [link.client.fingerprint]
    assert decision.decision.fingerprint == verdict.fingerprint
    (hello,) = link.server.stats.hellos[:1]
    assert hello.hello.queue_epoch == verdict.queue_epoch
    assert link.client.protocol == verdict.protocol == 2


async def test_reject_sends_nothing_into_the_queue() -> None:
    server = server_config(policy_checkpoint="act-insert-2025-01")  # not in the allowlist
    async with running(server) as link:
        await wait_for(lambda: link.server.stats.byes_received, "the client said bye")
        await wait_for(lambda: link.gateway.link_events("down"), "the link went down")
        stats, gateway = link.server.stats, link.gateway
        verdicts = gateway.handshakes()
    assert verdicts and all(v.decision == "REJECT" for v in verdicts)
    assert R.CHECKPOINT_NOT_ALLOWED in verdicts[0].reasons
    assert [d.decision.decision for d in stats.decisions] == ["REJECT"] * len(stats.decisions)
    assert stats.byes_received[0] == "handshake_rejected"
    assert stats.observations == 0 and stats.chunks_sent == 0
    assert gateway.chunk_lines() == []
    assert gateway.core.inspect_state().queue.pending_rows(gateway.now_ns()) == 0
    assert gateway.core.inspect_state().session is None
    assert link.client.counters.handshakes_accepted == 0


async def test_a_refused_handshake_says_what_the_server_offered() -> None:
    """The operator reads what to allow (or what to fix on the server): the offered
    checkpoint and configuration hash, with the core's reasons (for an openpi server the
    hash is the digest of its metadata frame, which the allowlist pins)."""
    server = server_config(policy_checkpoint="act-insert-2025-01")
    with structlog.testing.capture_logs() as logs:
        async with running(server) as link:
            await wait_for(lambda: link.gateway.handshakes(), "a handshake decided")
    refused = [e for e in logs if e["event"] == "policy handshake refused"]
    assert refused and refused[0]["policy_checkpoint"] == "act-insert-2025-01"
    assert refused[0]["config_hash"] == server.config_hash
    assert R.CHECKPOINT_NOT_ALLOWED in refused[0]["reasons"]


async def test_chunk_before_the_handshake_never_reaches_the_core() -> None:
    async with running(server_config(faults=FaultConfig(chunk_before_offer=True))) as link:
        await wait_for(lambda: link.gateway.admitted(), "a chunk admitted after reconnecting")
        counters, stats = link.client.counters, link.server.stats
        first_connection_chunk = f"policy-ref-e{stats.hellos[0].hello.queue_epoch}-s1"
    assert counters.protocol_violations == 1
    assert stats.byes_received[0] == "protocol_violation"
    assert counters.reconnects >= 1 and counters.handshakes_accepted >= 1
    # the unsolicited chunk was never fed to the core: it has no decision line at all
    assert stats.chunks_sent > counters.chunks_in
    assert all(line.chunk_id != first_connection_chunk for line in link.gateway.chunk_lines())
    assert link.gateway.refused_with(R.HANDSHAKE_REQUIRED) == []


async def test_protocol_one_server_is_accepted_at_version_one() -> None:
    async with running(server_config(protocol=(1, 1))) as link:
        await wait_for(lambda: len(link.gateway.admitted()) >= 2, "admitted chunks")
        (verdict,) = link.gateway.handshakes()
        connects = link.client.counters.connects
    assert verdict.protocol == 1 and link.client.protocol == 1
    # no clock_report under version 1 (the server would call it a violation and close)
    assert link.server.stats.violations == 0 and connects == 1


async def test_no_common_session_protocol_is_a_rejection() -> None:
    async with running(server_config(protocol=(3, 4))) as link:
        await wait_for(lambda: link.server.stats.byes_received, "the client said bye")
        verdict = link.gateway.handshakes()[0]
    assert verdict.decision == "REJECT" and R.PROTOCOL_MISMATCH in verdict.reasons
    assert link.server.stats.chunks_sent == 0


async def test_no_common_wire_protocol_ends_before_any_offer() -> None:
    async with running(server_config(wire_protocol=(4, 4))) as link:
        await wait_for(lambda: link.client.counters.byes_received >= 2, "two refusals")
        sent = link.server.stats.byes_sent
    assert link.gateway.handshakes() == []
    assert set(sent) == {"unsupported_version"}
    assert link.client.counters.reconnects >= 1


class _MisstatingGateway(LoopbackGateway):
    """States another control rate in its hello than the core decides with."""

    def client_side_hello(self) -> ClientHello:
        return msgspec.structs.replace(super().client_side_hello(), control_rate_hz=250.0)


async def test_server_checks_the_fingerprint() -> None:
    async with running(gateway=_MisstatingGateway()) as link:
        await wait_for(lambda: link.server.stats.byes_sent, "the server said bye")
        sent = list(link.server.stats.byes_sent)
        verdict = link.gateway.handshakes()[0]
    assert verdict.decision == "ACCEPT"  # the core accepted what it was told ...
    assert link.server.stats.fingerprints[0] != verdict.fingerprint  # ... the server disagrees
    assert sent[0] == "fingerprint_mismatch"
    assert link.server.stats.chunks_sent == 0
