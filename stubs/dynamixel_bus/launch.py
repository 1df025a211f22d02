"""Start the bus emulator in a child process and talk to its fault port (tests, benchmarks)."""

from __future__ import annotations

from typing import Any

from stubs.fault_control import inject
from stubs.process import EmulatorProcess

WIDE_TIMING = {"latency_budget_ms": 100.0, "call_timeout_s": 3.0}
"""Driver timing for talking to this emulator on a loaded machine (tests, benchmarks): a pty
reply can be late by 35 ms when two cores are shared, which the SDK's 34 ms budget would count
as a lost packet. Plain data, so the emulator does not depend on the driver."""


class BusEmulator:
    """``python -m stubs.dynamixel_bus`` in a subprocess; ``stop`` kills its process group."""

    def __init__(self, *args: str) -> None:
        self.process = EmulatorProcess("stubs.dynamixel_bus", *args)

    def __enter__(self) -> BusEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> BusEmulator:
        self.process.start()
        return self

    def stop(self) -> None:
        self.process.stop()

    @property
    def port(self) -> str:
        return str(self.process.info["port"])

    @property
    def fault_address(self) -> tuple[str, int]:
        return ("127.0.0.1", int(self.process.info["fault_port"]))

    def inject(self, fault: str, **fields: Any) -> None:
        """Switch on ``fault`` (``silent``, ``crc``, ``hardware_error``) or ``clear`` them all."""
        inject(self.fault_address, fault, **fields)
