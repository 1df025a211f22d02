"""Who the reference server talks to: TLS (optionally requiring a client certificate), a
bearer token, the ``warden.v1`` subprotocol, and ``GET /healthz`` for a load balancer or a
probe. Its own code, not warden's (kernel/shell/link_security.py is the robot's side): a
mistake on one side is not copied into the other.
"""

from __future__ import annotations

import hmac
import ssl
from dataclasses import dataclass, field
from http import HTTPStatus

from websockets.asyncio.server import ServerConnection
from websockets.http11 import Request, Response

SUBPROTOCOL = "warden.v1"


@dataclass(frozen=True, slots=True)
class Access:
    """The server's side of the link's security (all None: plain ``ws://``, anyone)."""

    cert_file: str | None = None
    key_file: str | None = None
    client_ca: str | None = None
    """PEM bundle the clients' certificates must chain to (None: no client certificate)."""
    token: str | None = field(default=None, repr=False)
    """The bearer token a client must present (None: none)."""

    def tls(self) -> ssl.SSLContext | None:
        if self.cert_file is None:
            return None
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        context.minimum_version = ssl.TLSVersion.TLSv1_2
        context.load_cert_chain(self.cert_file, self.key_file)
        if self.client_ca is not None:
            context.verify_mode = ssl.CERT_REQUIRED
            context.load_verify_locations(cafile=self.client_ca)
        return context

    def check(self, connection: ServerConnection, request: Request) -> Response | None:
        """Answer ``/healthz`` and refuse a wrong or missing token before the upgrade (None:
        go on with the websocket handshake)."""
        if request.path == "/healthz":
            return connection.respond(HTTPStatus.OK, "ok\n")
        if self.token is None:
            return None
        presented = request.headers.get("Authorization", "").encode()
        if hmac.compare_digest(presented, f"Bearer {self.token}".encode()):
            return None
        return connection.respond(HTTPStatus.UNAUTHORIZED, "a valid bearer token is required\n")


def read_token(path: str) -> str:
    with open(path, encoding="ascii") as file:
        return file.read().strip()
