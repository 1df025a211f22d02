"""Clock synchronisation over one connection of the policy link (docs/protocol.md, "Clock
synchronisation"): a burst of pings, the sample with the smallest round trip fed to the core,
reported to the server (protocol 2), refreshed periodically. A pong that does not echo its ping
or implies an implausible offset ends the connection; it never reaches the core."""

from __future__ import annotations

import asyncio

from kernel import wire
from kernel.core import events as ev
from kernel.shell.link_connection import Connection, LinkEnded
from kernel.shell.link_types import ClientConfig, Gateway
from kernel.wire import ByeReason, ClockSample, ProtocolViolation


class LinkClock:
    def __init__(self, config: ClientConfig, gateway: Gateway) -> None:
        self._config, self._gateway = config, gateway
        self.sample: ClockSample | None = None
        """The sync in force (the last burst's best sample)."""

    async def sync(self, conn: Connection) -> None:
        samples = [await self._ping(conn) for _ in range(self._config.clock_burst)]
        best = wire.best_sample(samples)
        if best is None:
            raise LinkEnded(ByeReason.PROTOCOL_VIOLATION, "no usable clock sample")
        self.sample = best
        conn.counters.clock_syncs += 1
        self._gateway.feed(ev.ClockSyncEvent(
            t=self._gateway.now_ns(), domain=wire.SERVER_CLOCK_DOMAIN, offset=best.offset,
            round_trip=best.round_trip))

    async def report(self, conn: Connection) -> None:
        if conn.version is not None and conn.version >= 2 and self.sample is not None:
            await conn.send(wire.ClockReport(offset=self.sample.offset,
                                             round_trip=self.sample.round_trip))

    async def refresh(self, conn: Connection) -> None:
        while True:
            await asyncio.sleep(self._config.clock_refresh_s)
            await self.sync(conn)
            await self.report(conn)

    @staticmethod
    def on_pong(conn: Connection, pong: wire.ClockPong, t_receive: int) -> None:
        # a pong for a ping that already timed out carries no usable sample: dropped
        if conn.pong is not None and pong.seq == conn.ping_seq and not conn.pong.done():
            conn.pong.set_result((pong, t_receive))

    async def _ping(self, conn: Connection) -> ClockSample:
        conn.ping_seq += 1
        conn.pong = answer = asyncio.get_running_loop().create_future()
        t0 = self._gateway.now_ns()
        try:
            await conn.send(wire.ClockPing(seq=conn.ping_seq, t0=t0))
            async with asyncio.timeout(self._config.clock_ping_timeout_s):
                pong, t1 = await answer
            sample = wire.clock_sample(t0, pong, t1)
        except TimeoutError as error:
            raise LinkEnded(ByeReason.CLOCK_TIMEOUT, "clock ping unanswered") from error
        except ProtocolViolation as error:  # an implausible clock: never fed to the core
            raise conn.violation(error) from error
        finally:
            conn.pong = None
        conn.counters.clock_round_trips += 1
        return sample
