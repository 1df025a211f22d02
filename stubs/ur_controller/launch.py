"""Start an emulated controller on a free 127.0.0.x (tests, benchmarks, demos).

ur_rtde always connects to ports 30004/29999/30003, so side-by-side emulators differ by address,
not port. Linux routes all of 127/8 to loopback without aliases. Another process may take an
address between our check and the emulator's bind, so starting retries on a fresh address.
"""

from __future__ import annotations

import random
import socket
from typing import Any

from stubs.fault_control import inject
from stubs.process import EmulatorProcess
from stubs.ur_controller.controller import DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT

MODULE = "stubs.ur_controller"
FIRST_OCTET, LAST_OCTET = 2, 254


def free_loopback_host(rng: random.Random | None = None) -> str:
    """A 127.0.0.x on which no process listens on any of the controller's ports."""
    rng = rng or random.Random()
    candidates = list(range(FIRST_OCTET, LAST_OCTET + 1))
    rng.shuffle(candidates)  # random order: parallel test runs rarely race for one address
    for octet in candidates:
        host = f"127.0.0.{octet}"
        if all(_can_listen(host, port) for port in (RTDE_PORT, DASHBOARD_PORT, SCRIPT_PORT)):
            return host
    raise RuntimeError("no free 127.0.0.x address for an emulated UR controller")


def _can_listen(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the emulator binds
        try:
            probe.bind((host, port))
        except OSError:
            return False
    return True


class EmulatedController:
    """One ``python -m stubs.ur_controller`` child process and its fault-control port."""

    def __init__(self, plant: str = "kinematic", version: str | None = None,
                 attempts: int = 5, host: str | None = None) -> None:
        """``host`` pins the address (one attempt); by default a free 127.0.0.x is found."""
        self.plant, self.version = plant, version
        self.attempts = 1 if host else attempts
        self.process: EmulatorProcess | None = None
        self.host = host or ""

    def __enter__(self) -> EmulatedController:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> EmulatedController:
        failure: Exception | None = None
        for _ in range(self.attempts):
            host = self.host or free_loopback_host()
            process = EmulatorProcess(MODULE, *self._arguments(host))
            try:
                self.process = process.start()
            except RuntimeError as error:  # address taken meanwhile: try another one
                failure = error
                continue
            self.host = host
            return self
        raise RuntimeError(f"could not start an emulated UR controller: {failure}")

    def stop(self) -> None:
        if self.process is not None:
            self.process.stop()
            self.process = None

    @property
    def info(self) -> dict[str, Any]:
        return self.process.info if self.process else {}

    def inject(self, fault: str, **fields: Any) -> None:
        inject((self.host, int(self.info["control_port"])), fault, **fields)

    def clear(self) -> None:
        self.inject("clear")

    def _arguments(self, host: str) -> list[str]:
        arguments = ["--host", host, "--plant", self.plant]
        if self.version:
            arguments += ["--version", self.version]
        return arguments
