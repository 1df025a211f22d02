"""The secured link (kernel/shell/link_security.py): ``wss://`` verified against the
manifest's CA bundle, a client certificate, a bearer token, the ``warden.v1`` subprotocol.

A real client and a real core against the reference server over loopback TLS (its own TLS
code, peer/access.py). Each refusal (a server certificate from another
authority, a wrong token, plain text to a TLS-only server, no client certificate where one is
required, a server that is not warden's) is a clear line, counted, and nothing moves: no
session, no chunk admitted, the arm where it started.
"""

from __future__ import annotations

import asyncio
import http.client
import ssl
from pathlib import Path

import numpy as np
import pytest
import structlog
from websockets.asyncio.client import connect
from websockets.asyncio.server import serve
from websockets.exceptions import InvalidStatus

from kernel.shell.link_security import SUBPROTOCOL, LinkSecurity, link_security
from kernel.shell.link_settings import AuthSettings, PolicySettings, TlsSettings
from peer.access import Access
from tests.wire.harness import Link, running, server_config, wait_for
from tests.wire.pki import Pki, make_pki

TOKEN = "d5c4-robot-cell-7"


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return make_pki(tmp_path_factory.mktemp("pki"))


def _token_file(directory: Path, token: str) -> Path:
    path = directory / "token"
    path.write_text(token + "\n")
    path.chmod(0o600)
    return path


def _security(pki: Pki, directory: Path, token: str | None = TOKEN, ca: Path | None = None,
              client_cert: bool = True) -> LinkSecurity:
    tls = TlsSettings(ca_file=str(ca or pki.ca),
                      cert_file=str(pki.client_cert) if client_cert else None,
                      key_file=str(pki.client_key) if client_cert else None)
    auth = None if token is None else AuthSettings(
        token_file=str(_token_file(directory, token)))
    return link_security(PolicySettings(launch=False, port=1, tls=tls, auth=auth), directory)


def _access(pki: Pki, other: bool = False, client_ca: bool = True) -> Access:
    cert, key = ((pki.other_server_cert, pki.other_server_key) if other else
                 (pki.server_cert, pki.server_key))
    return Access(cert_file=str(cert), key_file=str(key),
                  client_ca=str(pki.ca) if client_ca else None, token=TOKEN)


async def _refused(link: Link, needle: str) -> str:
    """Wait for the client's refusal; check that nothing of a session happened."""
    await wait_for(lambda: link.client.counters.connects_refused >= 2, "two refused connects")
    client, gateway = link.client, link.gateway
    assert client.refusal is not None and needle in client.refusal, client.refusal
    assert client.counters.handshakes_accepted == 0 and not gateway.handshakes()
    assert not gateway.chunk_lines() and link.server.stats.chunks_sent == 0
    np.testing.assert_array_equal(gateway.q, gateway.config.initial_q)
    return client.refusal


async def test_tls_with_a_client_certificate_and_a_token_carries_the_session(
        pki: Pki, tmp_path: Path) -> None:
    server = server_config(access=_access(pki))
    async with running(server, url="wss://127.0.0.1:{port}",
                       security=_security(pki, tmp_path)) as link:
        await wait_for(lambda: len(link.gateway.admitted()) >= 3, "three chunks admitted")
        assert link.client.counters.connects_refused == 0


async def test_a_server_certificate_from_another_authority_is_refused(
        pki: Pki, tmp_path: Path) -> None:
    server = server_config(access=_access(pki, other=True))
    with structlog.testing.capture_logs() as logs:
        async with running(server, url="wss://127.0.0.1:{port}",
                           security=_security(pki, tmp_path)) as link:
            why = await _refused(link, "certificate was refused")
    assert "[policy.tls]" in why
    warned = [e for e in logs if e["event"] == "policy server connection refused"]
    assert len(warned) == 1, warned  # said once, not at every retry
    assert link.server.stats.connections == 0


async def test_a_wrong_token_is_refused(pki: Pki, tmp_path: Path) -> None:
    server = server_config(access=_access(pki))
    async with running(server, url="wss://127.0.0.1:{port}",
                       security=_security(pki, tmp_path, token="not-the-token")) as link:
        await _refused(link, "refused this robot's credentials (HTTP 401)")


async def test_no_token_is_refused(pki: Pki, tmp_path: Path) -> None:
    server = server_config(access=_access(pki))
    async with running(server, url="wss://127.0.0.1:{port}",
                       security=_security(pki, tmp_path, token=None)) as link:
        await _refused(link, "HTTP 401")


async def test_plain_text_to_a_tls_only_server_is_refused(pki: Pki, tmp_path: Path) -> None:
    server = server_config(access=_access(pki))
    async with running(server, url="ws://127.0.0.1:{port}", security=LinkSecurity()) as link:
        await _refused(link, "without [policy.tls]")


async def test_no_client_certificate_where_the_server_requires_one_is_refused(
        pki: Pki, tmp_path: Path) -> None:
    server = server_config(access=_access(pki))
    async with running(server, url="wss://127.0.0.1:{port}",
                       security=_security(pki, tmp_path, client_cert=False)) as link:
        await _refused(link, "client certificate")


async def test_a_server_that_does_not_speak_warden_v1_is_refused(tmp_path: Path) -> None:
    """A websocket server that selects no subprotocol (a foreign service on the port)."""
    async def echo(ws) -> None:  # type: ignore[no-untyped-def]
        async for message in ws:
            await ws.send(message)

    async with serve(echo, "127.0.0.1", 0) as foreign:
        port = next(iter(foreign.sockets)).getsockname()[1]
        async with running(port=port) as link:
            await _refused(link, f"did not select the {SUBPROTOCOL} subprotocol")


async def test_a_foreign_client_fails_at_connect_and_healthz_answers(pki: Pki) -> None:
    """The reference server's side: a websocket client that does not offer ``warden.v1`` is
    refused in the HTTP upgrade (400), before any frame; ``GET /healthz`` answers 200 without
    a token."""
    from stubs.policy_server import PolicyServer

    context = ssl.create_default_context(cafile=str(pki.ca))
    context.load_cert_chain(str(pki.client_cert), str(pki.client_key))
    async with PolicyServer(server_config(access=_access(pki))) as server:
        url = f"wss://127.0.0.1:{server.port}"
        headers = [("Authorization", f"Bearer {TOKEN}")]
        with pytest.raises(InvalidStatus) as refused:
            async with connect(url, ssl=context, additional_headers=headers):
                pass
        assert refused.value.response.status_code == 400
        async with connect(url, ssl=context, additional_headers=headers,
                           subprotocols=[SUBPROTOCOL]) as ws:  # type: ignore[list-item]
            assert ws.subprotocol == SUBPROTOCOL

        def healthz() -> tuple[int, bytes]:
            probe = http.client.HTTPSConnection("127.0.0.1", server.port, context=context,
                                                timeout=5)
            probe.request("GET", "/healthz")
            answer = probe.getresponse()
            return answer.status, answer.read()

        assert await asyncio.to_thread(healthz) == (200, b"ok\n")
