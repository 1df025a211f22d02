"""Fault injection for the reference policy server (test tooling).

Two kinds of fault:

- per-chunk faults, given as a fraction of chunks: ``drop``, ``duplicate``, ``reorder`` (hold
  one chunk back and send it after the next), ``spike`` (extra latency of ``spike_ms``),
  ``garbage`` (a chunk frame whose body cannot be decoded: a MALFORMED refusal), ``nonfinite``
  (a NaN action), ``wrong_dim`` (one action dimension too many). Fractions are applied on a
  fixed, deterministic pattern (0.5 hits every second chunk, 1/3 every third), so a test knows
  which chunk is hit without depending on a random seed;
- per-connection faults after the N-th chunk sent on a connection, for the first
  ``affect_connections`` connections: a frame that is not an envelope (``garbage_frame_after``),
  a frame over the size limit (``oversized_after``), an unknown message type
  (``unknown_type_after``), a clean close (``close_after``) or total silence, heartbeats included
  (``stall_after``).

Floods, on the affected connections once a session is accepted (what a misbehaving server
costs the robot side): ``flood_chunks_per_s`` (that many extra chunks a second, each the last
answer again under a new chunk id and sequence, so it cites an observation already answered;
before the first answer, a chunk citing an observation never sent),
``junk_frame_bytes`` (a frame of that many bytes that is not an envelope, ``junk_frames_per_s``
times a second), ``big_chunk_rows`` (every answer carries that many actions: 20000 rows of 6
float64 are a 960 kB chunk).

And: ``clock_t_server`` (every clock pong on an affected connection claims this server time,
however implausible: ``18446744073709551615`` is 2**64 - 1),
``checkpoint`` (every chunk claims another checkpoint than the one offered),
``chunk_before_offer`` (a chunk sent before the handshake), ``resend_on_reconnect`` (after a new
handshake, first resend the last N chunks produced before it, dropped ones included).
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, fields

import msgspec

from peer.envelope import (
    ChunkEnvelope,
    chunk_body_frame,
    encode_chunk_body,
    encode_chunk_frame,
)
from peer.protocol import MAX_FRAME_BYTES, ArrayPayload, encode_raw

_FRACTIONS = ("drop", "duplicate", "reorder", "spike", "garbage", "nonfinite", "wrong_dim")


@dataclass(frozen=True, slots=True)
class FaultConfig:
    drop: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    spike: float = 0.0
    spike_ms: float = 100.0
    garbage: float = 0.0
    nonfinite: float = 0.0
    wrong_dim: float = 0.0
    checkpoint: str | None = None
    clock_t_server: int | None = None
    garbage_frame_after: int | None = None
    oversized_after: int | None = None
    unknown_type_after: int | None = None
    close_after: int | None = None
    stall_after: int | None = None
    chunk_before_offer: bool = False
    resend_on_reconnect: int = 0
    flood_chunks_per_s: float = 0.0
    junk_frame_bytes: int = 0
    junk_frames_per_s: float = 10.0
    big_chunk_rows: int = 0
    affect_connections: int = 1

    def __post_init__(self) -> None:
        for name in _FRACTIONS:
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"fault {name} is a fraction in [0, 1]")

    @classmethod
    def parse(cls, pairs: list[str]) -> FaultConfig:
        """``NAME=VALUE`` pairs from the command line (``--fault drop=0.5``)."""
        types = {f.name: f.type for f in fields(cls)}
        values: dict[str, object] = {}
        for pair in pairs:
            name, _, text = pair.partition("=")
            if name not in types:
                raise ValueError(f"unknown fault {name!r} (known: {', '.join(types)})")
            values[name] = _value(str(types[name]), text)
        return cls(**values)  # type: ignore[arg-type]


def _value(kind: str, text: str) -> object:
    if kind.startswith("bool"):
        return text.lower() in ("1", "true", "yes", "")
    if kind.startswith("str"):
        return text
    if kind.startswith("int"):
        return int(text)
    return float(text)


class _Pattern:
    """Hits a fraction of calls on a fixed pattern: 0.5 → every 2nd, 1.0 → every call."""

    def __init__(self, fraction: float) -> None:
        self.fraction = fraction
        self.calls = 0

    def hit(self) -> bool:
        before = math.floor(self.calls * self.fraction + 1e-9)
        self.calls += 1
        return math.floor(self.calls * self.fraction + 1e-9) > before


@dataclass(frozen=True, slots=True)
class ChunkFaults:
    """What happens to one chunk."""

    drop: bool = False
    duplicate: bool = False
    reorder: bool = False
    spike_s: float = 0.0
    garbage: bool = False
    nonfinite: bool = False
    wrong_dim: bool = False


class FaultPlan:
    """Decides, chunk by chunk, which faults apply (shared by all connections of a server)."""

    def __init__(self, config: FaultConfig) -> None:
        self.config = config
        self._patterns = {name: _Pattern(getattr(config, name)) for name in _FRACTIONS}

    def next_chunk(self) -> ChunkFaults:
        hits = {name: pattern.hit() for name, pattern in self._patterns.items()}
        spike = self.config.spike_ms / 1000.0 if hits.pop("spike") else 0.0
        return ChunkFaults(spike_s=spike, **hits)


# -- bad frames --------------------------------------------------------------------------------


def garbage_chunk_body(chunk: ChunkEnvelope) -> bytes:
    """A chunk body that decodes as MessagePack but not as a chunk: its action bytes are cut
    short, so the client can still name the chunk it refuses."""
    actions = chunk.actions
    short = ArrayPayload(dtype=actions.dtype, shape=actions.shape, data=actions.data[:-3])
    return encode_chunk_body(msgspec.structs.replace(chunk, actions=short))


def junk_frame(size: int) -> bytes:
    """``size`` bytes that are not an envelope (0xc1 never starts a MessagePack value)."""
    return b"\xc1" * size


def garbage_frame() -> bytes:
    """Not an envelope at all: 0xc1 is a byte MessagePack never uses."""
    return b"\xc1garbage\x00\xff"


def oversized_frame() -> bytes:
    return chunk_body_frame(msgspec.msgpack.encode(b"\x00" * (MAX_FRAME_BYTES + 1)))


def unknown_type_frame() -> bytes:
    return encode_raw("telemetry", msgspec.msgpack.encode({"note": "not in this protocol"}))


# -- floods ------------------------------------------------------------------------------------

Send = Callable[[bytes], Awaitable[None]]


async def flood_chunks(per_s: float, last: Callable[[], ChunkEnvelope],
                       next_sequence: Callable[[int], int], send: Send) -> None:
    """The chunk ``last()`` returns, ``per_s`` times a second, each under a new id and
    sequence (sent in batches every 10 ms)."""
    batch_s = 0.01
    owed = 0.0
    while True:
        await asyncio.sleep(batch_s)
        chunk = last()
        owed += per_s * batch_s
        for _ in range(int(owed)):
            sequence = next_sequence(chunk.queue_epoch)
            copy = msgspec.structs.replace(chunk, chunk_id=f"flood-{sequence}",
                                           sequence=sequence)
            await send(encode_chunk_frame(copy))
        owed -= int(owed)


async def flood_junk(size: int, per_s: float, send: Send) -> None:
    """A frame of ``size`` bytes that is not an envelope, ``per_s`` times a second."""
    frame = junk_frame(size)
    while True:
        await asyncio.sleep(1.0 / per_s)
        await send(frame)
