"""One websocket connection of the policy link: its state, how it ends, and how it sends."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from websockets.asyncio.client import ClientConnection
from websockets.exceptions import ConnectionClosed

from kernel.shell.link_types import LinkCounters
from kernel.wire import ByeReason

CLOSE_TOO_BIG = 1009
SILENCE = frozenset({ByeReason.HEARTBEAT_TIMEOUT, ByeReason.CLOCK_TIMEOUT,
                     ByeReason.HANDSHAKE_TIMEOUT})
"""The ends that mean the peer stopped answering."""


class LinkEnd(StrEnum):
    """How a connection ended, as far as restarting a launched server is concerned."""

    SILENT = "silent"
    """The peer stopped answering (heartbeat, clock or handshake timeout)."""
    UNREACHABLE = "unreachable"
    """No connection could be opened (refused, or no websocket handshake in time)."""
    OTHER = "other"


class LinkEnded(Exception):
    """This connection is over; ``bye`` is what to tell the peer (None: nothing to say)."""

    def __init__(self, bye: ByeReason | None, detail: str, oversized: bool = False) -> None:
        super().__init__(detail)
        self.bye = bye
        self.detail = detail
        self.oversized = oversized


@dataclass(slots=True, eq=False)
class Connection:
    """One websocket connection: the bytes moved, nothing of the session (the protocol object
    holds that: the negotiated version, the timers, the clock exchange)."""

    ws: ClientConnection
    counters: LinkCounters

    async def send_data(self, data: bytes) -> None:
        """Send one encoded frame; a closed connection ends the link (:class:`LinkEnded`)."""
        try:
            await self.ws.send(data)
        except ConnectionClosed as error:
            raise closed(error) from error
        self.counters.frames_out += 1
        self.counters.bytes_out += len(data)


def closed(error: ConnectionClosed) -> LinkEnded:
    if error.sent is not None and error.sent.code == CLOSE_TOO_BIG:
        return LinkEnded(None, "frame over the size limit", oversized=True)
    return LinkEnded(None, f"connection closed ({error})")
