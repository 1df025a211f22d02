"""Where a CiA 402 emulator process can run its bus (cells, tests, benchmarks)."""

from __future__ import annotations

import random


def unique_udp_bus() -> tuple[str, int]:
    """A multicast group and port nobody else on this host is likely to use right now: parallel
    runs on one machine must not hear each other's drives."""
    rng = random.SystemRandom()
    group = f"239.{rng.randint(1, 254)}.{rng.randint(1, 254)}.{rng.randint(1, 254)}"
    return group, rng.randint(20000, 60000)
