"""Identity memory: which chunks this client has seen, across reconnections.

Duplicates are recognised by ``(chunk_id, payload_hash)`` and ignored idempotently; the same
``chunk_id`` with another payload is an ``ID_CONFLICT``. The memory is bounded (oldest forgotten
first) and deliberately survives reconnection and epoch changes, so that a resend after a
reconnect is still recognised as the chunk it is.
"""

from __future__ import annotations

from collections import OrderedDict
from enum import StrEnum
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from assurance.rtc import RtcPrefix


class Seen(StrEnum):
    NEW = "new"
    DUPLICATE = "duplicate"
    CONFLICT = "conflict"


class ChunkMemory:
    def __init__(self, capacity: int = 4096) -> None:
        if capacity <= 0:
            raise ValueError("capacity must be positive")
        self.capacity = capacity
        self._hashes: OrderedDict[str, str] = OrderedDict()

    def classify(self, chunk_id: str, payload_hash: str) -> Seen:
        known = self._hashes.get(chunk_id)
        if known is None:
            return Seen.NEW
        return Seen.DUPLICATE if known == payload_hash else Seen.CONFLICT

    def remember(self, chunk_id: str, payload_hash: str) -> None:
        """Record the first payload seen under ``chunk_id``; a conflict never overwrites it."""
        if chunk_id in self._hashes:
            return
        self._hashes[chunk_id] = payload_hash
        if len(self._hashes) > self.capacity:
            self._hashes.popitem(last=False)

    def __len__(self) -> int:
        return len(self._hashes)


class ObservationLog:
    """The client's own record of the observations it sent in this session (bounded).

    This record, not the server's claim, is authoritative for an observation's time. An
    observation is *pending* from when it is recorded until a chunk that answers it is admitted;
    after that it is *answered* (until a new queue epoch purges that answer), and any further
    chunk citing it answers nothing the client asked for.
    """

    def __init__(self, capacity: int = 1024) -> None:
        self.capacity = capacity
        self._times: OrderedDict[str, int] = OrderedDict()
        self._answered: set[str] = set()
        self._prefixes: dict[str, tuple[RtcPrefix, int]] = {}
        self.latest: str | None = None

    def record(self, observation_id: str, t_event: int, prefix: RtcPrefix | None = None,
               queue_version: int = 0) -> None:
        """An observation sent at ``t_event``, with the committed prefix it carried, if any, and
        the version of the queue that prefix was taken from."""
        self._times[observation_id] = t_event
        self._times.move_to_end(observation_id)
        self._answered.discard(observation_id)
        self._prefixes.pop(observation_id, None)
        if prefix is not None:
            self._prefixes[observation_id] = (prefix, queue_version)
        self.latest = observation_id
        if len(self._times) > self.capacity:
            oldest, _ = self._times.popitem(last=False)
            self._answered.discard(oldest)
            self._prefixes.pop(oldest, None)

    def time_of(self, observation_id: str) -> int | None:
        return self._times.get(observation_id)

    def prefix_of(self, observation_id: str) -> tuple[RtcPrefix, int] | None:
        """The committed prefix the observation carried (real-time chunking), if any, and the
        queue's version when it was taken."""
        return self._prefixes.get(observation_id)

    def answer(self, observation_id: str) -> None:
        """An admitted chunk answered ``observation_id``: it is no longer pending."""
        if observation_id in self._times:
            self._answered.add(observation_id)

    def answered(self, observation_id: str) -> bool:
        """True for an observation of this session that an admitted chunk answered already."""
        return observation_id in self._answered

    def forget_answers(self) -> None:
        """A new queue epoch purged every admitted answer: nothing recorded counts as answered
        any more (an answer made for the new epoch is judged by every gate again)."""
        self._answered.clear()

    def clear(self) -> None:
        """A new session: observations of the old one are no longer this client's."""
        self._times.clear()
        self._answered.clear()
        self._prefixes.clear()
        self.latest = None
