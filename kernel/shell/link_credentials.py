"""What connecting to the policy server needs beyond its address: the TLS context, the
token and the subprotocol (kernel/shell/link_security.py reads them from the manifest and
explains a refusal). Plain data and pure functions: the protocol objects' modules reach it
through the client's configuration, and it reaches no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from kernel.shell.link_settings import PolicyProtocol

if TYPE_CHECKING:
    import ssl

SUBPROTOCOL = "warden.v1"
"""The websocket subprotocol of warden's protocol (docs/protocol.md)."""


class Token:
    """A secret that never shows itself in a log line, a repr or a traceback's locals."""

    __slots__ = ("_value",)

    def __init__(self, value: str) -> None:
        self._value = value

    def reveal(self) -> str:
        return self._value

    def __repr__(self) -> str:
        return "Token(<redacted>)"


@dataclass(frozen=True, slots=True)
class LinkSecurity:
    """What connecting needs beyond the host and port (the default: plain, anonymous)."""

    tls: ssl.SSLContext | None = None
    server_name: str | None = None
    token: Token | None = None

    @property
    def scheme(self) -> str:
        return "wss" if self.tls is not None else "ws"

    def headers(self, protocol: PolicyProtocol) -> list[tuple[str, str]]:
        """The credentials in the header the server's side reads: ``Bearer`` for warden's
        protocol, ``Api-Key`` as openpi's client sends it (openpi's server does not check it;
        a proxy in front of it may)."""
        if self.token is None:
            return []
        kind = "Api-Key" if protocol is PolicyProtocol.OPENPI else "Bearer"
        return [("Authorization", f"{kind} {self.token.reveal()}")]


def subprotocols(protocol: PolicyProtocol) -> list[str] | None:
    """The subprotocols the client offers (openpi's server negotiates none)."""
    return [SUBPROTOCOL] if protocol is PolicyProtocol.WARDEN else None


def foreign_server(protocol: PolicyProtocol, selected: str | None) -> str | None:
    """Why a server that accepted the connection is not one to talk to, or None."""
    wanted = subprotocols(protocol)
    if wanted is not None and selected not in wanted:
        return (f"the policy server did not select the {SUBPROTOCOL} subprotocol (it selected "
                f"{selected or 'none'}): not a warden policy server")
    return None
