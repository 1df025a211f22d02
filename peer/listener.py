"""Where a policy server of warden's protocol listens: a websocket server with the ``warden.v1``
subprotocol, the access rules of :mod:`peer.access` (TLS, a client certificate, a bearer token,
``/healthz``) and no compression or websocket pings (the protocol has its own heartbeats)."""

from __future__ import annotations

from collections.abc import Awaitable, Callable

from websockets.asyncio.server import Server, ServerConnection
from websockets.asyncio.server import serve as ws_serve

from peer.access import SUBPROTOCOL, Access

Handler = Callable[[ServerConnection], Awaitable[None]]


class Listener:
    """One listening socket: :meth:`open`, then :attr:`port`, :meth:`serve_forever`,
    :meth:`close`."""

    def __init__(self) -> None:
        self._server: Server | None = None

    async def open(self, handler: Handler, host: str, port: int, max_frame_bytes: int,
                   access: Access) -> None:
        self._server = await ws_serve(
            handler, host, port, max_size=max_frame_bytes, compression=None,
            ping_interval=None, close_timeout=1.0, ssl=access.tls(),
            subprotocols=[SUBPROTOCOL], process_request=access.check,  # type: ignore[list-item]
        )

    @property
    def port(self) -> int:
        return int(next(iter(self._listening().sockets)).getsockname()[1])

    async def serve_forever(self) -> None:
        await self._listening().serve_forever()

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None

    def _listening(self) -> Server:
        if self._server is None:
            raise RuntimeError("the server is not listening")
        return self._server
