"""A minimal client of the UR dashboard server (port 29999), with a deadline on every call.

The protocol is a line of text each way (UR's "Dashboard Server" manual): a welcome line on
connect, then one answer per command. The monitor needs three commands: ``is in remote
control`` (at start: a controller in local mode may refuse program commands, and a stop path
that may be refused is none), ``running`` (a cheap probe that the path still answers) and
``stop`` ("Stops running program and returns when stopping is completed", from 3.3 on; answer
``Stopped``, or ``Failed to execute: stop``). Plain sockets rather than ur_rtde's
``DashboardClient``: every call here must end within its deadline, whatever the controller does.
"""

from __future__ import annotations

import contextlib
import socket

PORT = 29999
WELCOME = "Connected: Universal Robots Dashboard Server"
STOPPED = "Stopped"


class DashboardError(OSError):
    """The dashboard server cannot be reached, or did not answer as one."""


class Dashboard:
    def __init__(self, host: str, timeout_s: float, stop_timeout_s: float) -> None:
        self.host, self.timeout_s, self.stop_timeout_s = host, timeout_s, stop_timeout_s
        self._sock: socket.socket | None = None
        self._reader = None

    @property
    def address(self) -> str:
        return f"{self.host}:{PORT}"

    def connect(self) -> None:
        """Raises:
            DashboardError: nothing answers, or not as a UR dashboard server.
        """
        self.close()
        try:
            sock = socket.create_connection((self.host, PORT), timeout=self.timeout_s)
        except OSError as error:
            raise DashboardError(f"cannot reach the UR dashboard server at {self.address} "
                                 f"({error})") from error
        self._sock, self._reader = sock, sock.makefile("rb")
        welcome = self._line(self.timeout_s)
        if not welcome.startswith(WELCOME):
            self.close()
            raise DashboardError(f"{self.address} does not answer as a UR dashboard server "
                                 f"(welcome {welcome[:60]!r})")

    def ask(self, command: str, timeout_s: float | None = None) -> str:
        """One command, its answer line.

        Raises:
            DashboardError: not connected, or no answer within the deadline.
        """
        if self._sock is None:
            raise DashboardError(f"not connected to {self.address}")
        try:
            self._sock.settimeout(self.timeout_s)
            self._sock.sendall(command.encode() + b"\n")
        except OSError as error:
            self.close()
            raise DashboardError(f"{self.address}: {command!r} not sent ({error})") from error
        return self._line(timeout_s or self.timeout_s)

    def stop(self) -> str:
        """``stop``; reconnects once if the connection went away. The answer line.

        Raises:
            DashboardError: neither the connection nor a new one carried it.
        """
        try:
            return self.ask("stop", self.stop_timeout_s)
        except DashboardError:
            self.connect()
            return self.ask("stop", self.stop_timeout_s)

    def close(self) -> None:
        if self._reader is not None:
            with contextlib.suppress(OSError):
                self._reader.close()
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.close()
        self._sock = self._reader = None

    def _line(self, timeout_s: float) -> str:
        if self._sock is None or self._reader is None:
            raise DashboardError(f"not connected to {self.address}")
        try:
            self._sock.settimeout(timeout_s)
            raw = self._reader.readline(1024)
        except OSError as error:
            self.close()
            raise DashboardError(f"{self.address}: no answer within {timeout_s:g} s "
                                 f"({error})") from error
        if not raw:
            self.close()
            raise DashboardError(f"{self.address} closed the connection")
        return raw.decode(errors="replace").strip()
