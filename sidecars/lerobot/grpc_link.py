"""The sidecar's side of LeRobot's ``AsyncInference`` gRPC service, as LeRobot's own
``RobotClient`` uses it: ``Ready`` (the server forgets any earlier client), then
``SendPolicyInstructions`` (it loads the policy), then per observation a ``SendObservations``
stream and a ``GetActions``. Messages are bytes encoded by ``protobuf.py``; grpcio passes them
through untouched (no serializer), so neither protobuf nor LeRobot's generated stub is needed.
The channel is plain HTTP/2, as LeRobot's server listens only on an insecure port: keep it on
loopback or a cell network you trust (``docs/protocol.md``).
"""

from __future__ import annotations

import grpc

from sidecars.lerobot import protobuf
from sidecars.lerobot.config import LeRobot

_SERVICE = "/transport.AsyncInference/"


class LinkLost(ConnectionError):
    """A call failed or timed out; the message has gRPC's status and details."""


class LeRobotLink:
    """``async with LeRobotLink(settings) as link:`` then ``await link.prepare(setup)`` once per
    robot session, and ``await link.infer(observation)`` per observation."""

    def __init__(self, settings: LeRobot) -> None:
        self.settings = settings
        self._channel: grpc.aio.Channel | None = None

    async def __aenter__(self) -> LeRobotLink:
        limit = protobuf.MESSAGE_LIMIT
        self._channel = grpc.aio.insecure_channel(self.settings.server, options=[
            ("grpc.max_receive_message_length", limit), ("grpc.max_send_message_length", limit),
        ])
        return self

    async def __aexit__(self, *exc: object) -> None:
        if self._channel is not None:
            await self._channel.close()
            self._channel = None

    async def prepare(self, setup: bytes) -> None:
        """``Ready``, then the pickled ``RemotePolicyConfig``: the server loads the policy."""
        timeout = self.settings.setup_timeout_s
        await self._call("Ready", protobuf.EMPTY, timeout)
        await self._call("SendPolicyInstructions", protobuf.policy_setup(setup), timeout)

    async def infer(self, observation: bytes) -> bytes:
        """The ``Actions.data`` answering one pickled ``TimedObservation`` (empty: the server
        answered ``Empty``)."""
        channel = self._open()
        send = channel.stream_unary(_SERVICE + "SendObservations")
        timeout = self.settings.reply_timeout_s
        try:
            await send(iter(list(protobuf.observation_pieces(observation))), timeout=timeout)
        except grpc.aio.AioRpcError as error:
            raise _lost("SendObservations", error) from None
        reply = await self._call("GetActions", protobuf.EMPTY, timeout)
        try:
            return protobuf.actions_data(reply)
        except protobuf.MalformedMessage as error:
            raise LinkLost(f"GetActions: {error}") from None

    async def _call(self, method: str, request: bytes, timeout: float) -> bytes:
        call = self._open().unary_unary(_SERVICE + method)
        try:
            return await call(request, timeout=timeout)
        except grpc.aio.AioRpcError as error:
            raise _lost(method, error) from None

    def _open(self) -> grpc.aio.Channel:
        if self._channel is None:
            raise RuntimeError("use the link inside `async with`")
        return self._channel


def _lost(method: str, error: grpc.aio.AioRpcError) -> LinkLost:
    return LinkLost(f"{method}: {error.code().name}: {error.details()}")
