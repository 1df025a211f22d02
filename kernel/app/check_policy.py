"""``warden check``'s policy link rows: the server a run would talk to, reached the way the run
reaches it (``wss://`` with the manifest's CA bundle and client certificate, the bearer token,
the ``warden.v1`` subprotocol), without a session.

Nothing of the protocol is spoken: no hello, no observation, so nothing the server answers
can reach a core or an arm. For warden's own protocol the connection is closed as soon as it
is open (the offer comes only after a hello: the run's handshake decides it). An openpi
server sends its metadata frame when a connection opens; its digest is the ``config_hash``
the allowlist must pin, so check reads that one frame and says whether the allowlist holds
it, with the value to pin when it does not.
"""

from __future__ import annotations

import asyncio
import contextlib

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake

from drivers.readiness import CheckVerdict, Finding, judged, not_exercised
from kernel.manifest import Manifest
from kernel.openpi_wire import OpenpiError, decode_metadata
from kernel.shell.link_credentials import foreign_server, subprotocols
from kernel.shell.link_openpi import CONFIG_HASH_PREFIX
from kernel.shell.link_security import why_refused
from kernel.shell.link_settings import PolicyProtocol
from kernel.shell.supervisor import describe

OPEN_TIMEOUT_S = 5.0
METADATA_TIMEOUT_S = 5.0
LINK = "policy server"
CONFIGURATION = "policy configuration"


async def policy_rows(manifest: Manifest) -> list[Finding]:
    """The link's row and, for an openpi server, its configuration's row."""
    policy = manifest.policy
    if policy.launch:
        return [not_exercised(LINK, "launched by the run",
                              "check starts no policy server (launch = true)")]
    security = manifest.link_security
    url = f"{security.scheme}://{policy.host}:{policy.port}"
    expected = _expected(manifest, url)
    try:
        async with connect(
            url, open_timeout=OPEN_TIMEOUT_S, close_timeout=1.0, compression=None,
            ping_interval=None, proxy=None, max_size=policy.max_frame_bytes,
            additional_headers=security.headers(policy.protocol),
            subprotocols=subprotocols(policy.protocol),  # type: ignore[arg-type]
            **({} if security.tls is None else {"ssl": security.tls,
                                                 "server_hostname": security.server_name}),
        ) as ws:
            foreign = foreign_server(policy.protocol, ws.subprotocol)
            if foreign is not None:
                return [judged(LINK, expected, "a websocket server", [foreign])]
            rows = [judged(LINK, expected, _measured(manifest, ws), [])]
            if policy.protocol is PolicyProtocol.OPENPI:
                rows.append(await _configuration(manifest, ws))
            else:
                rows.append(not_exercised(CONFIGURATION, "the offer the run's handshake decides",
                                          "check sends no hello, so the server offers nothing"))
            return rows
    except (OSError, TimeoutError, InvalidHandshake) as error:
        why = why_refused(error, tls=security.tls is not None) or (
            f"not reachable ({describe(error)})")
        return [judged(LINK, expected, "not connected", [why])]


def _expected(manifest: Manifest, url: str) -> str:
    security, protocol = manifest.link_security, manifest.policy.protocol
    parts = [f"a websocket at {url}"]
    if security.tls is not None:
        parts.append(f"its certificate verified for {security.server_name}")
    if security.token is not None:
        parts.append("the token accepted")
    if protocol is PolicyProtocol.WARDEN:
        parts.append("warden.v1 selected")
    return ", ".join(parts)


def _measured(manifest: Manifest, ws: ClientConnection) -> str:
    security = manifest.link_security
    said = ["connected"]
    if security.tls is not None:
        said.append("certificate verified")
    if security.token is not None:
        said.append("token accepted")
    if ws.subprotocol is not None:
        said.append(f"subprotocol {ws.subprotocol}")
    return ", ".join(said)


async def _configuration(manifest: Manifest, ws: ClientConnection) -> Finding:
    """The openpi server's metadata frame against the allowlist."""
    openpi = manifest.policy.openpi
    checkpoint = openpi.policy_checkpoint if openpi is not None else ""
    expected = f"its metadata digest allowed with policy_checkpoint {checkpoint!r}"
    try:
        async with asyncio.timeout(METADATA_TIMEOUT_S):
            frame = await ws.recv()
        if isinstance(frame, str):
            raise OpenpiError("a text frame where the metadata frame belongs")
        config_hash = CONFIG_HASH_PREFIX + decode_metadata(frame).digest
    except (TimeoutError, ConnectionClosed, OpenpiError) as error:
        return judged(CONFIGURATION, expected, "no metadata frame",
                      [f"the server sent no usable metadata frame ({describe(error)})"])
    finally:
        with contextlib.suppress(ConnectionClosed):
            await ws.close()
    if (checkpoint, config_hash) in manifest.core.allowlist:
        return judged(CONFIGURATION, expected, f"config_hash {config_hash}", [])
    return Finding(name=CONFIGURATION, expected=expected, measured=f"config_hash {config_hash}",
                   verdict=CheckVerdict.NOT_READY,
                   reason=f"not in the allowlist: if this is the server you mean, add "
                          f"[[allowlist]] policy_checkpoint = {checkpoint!r}, "
                          f"config_hash = {config_hash!r}")


__all__ = ["policy_rows"]
