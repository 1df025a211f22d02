"""The monitor's watch on a UR controller: a second RTDE receive session, and the dashboard.

A UR controller serves several RTDE clients at once, each with its own output recipe; the
monitor's session reads the joints, their speeds and the wrist force (``actual_TCP_force``)
through ur_rtde's ``RTDEReceiveInterface``, independent of warden's sessions. Its stop path is
the dashboard server's ``stop``: the controller brings the arm to rest and stops the running
program (warden's ``rtde_control`` script), so nothing warden sends afterwards moves the arm
until a new script is uploaded.

ur_rtde's constructors hold the GIL while they connect, some of it without a deadline: the
ports are checked with plain sockets first (:func:`_reachable`), so a wrong or dead host is
refused within ``device_timeout_ms`` instead of freezing the monitor.
"""

from __future__ import annotations

import contextlib
import math
import socket
import time
from typing import Any

from kernel.safety.checks import Sample
from kernel.safety.dashboard import PORT as DASHBOARD_PORT
from kernel.safety.dashboard import STOPPED, Dashboard, DashboardError
from kernel.safety.settings import SafetySettings
from kernel.safety.view import MonitorView
from kernel.safety.watch import DeviceLost, DeviceUnreachable, StopResult

RTDE_PORT = 30004
VARIABLES = ["timestamp", "actual_q", "actual_qd", "actual_TCP_force", "runtime_state"]
CONNECT_TIMEOUT_S = 2.0
STOP_TIMEOUT_S = 5.0
"""The dashboard's ``stop`` answers once the arm is at rest: allow for a long deceleration."""


class URWatch:
    can_stop = True
    lives_in_warden = False

    def __init__(self, host: str, device_timeout_s: float) -> None:
        self.host = host
        self.device_timeout_s = device_timeout_s
        self.description = f"ur_rtde controller at {host} (own RTDE receive session)"
        self.stop_path = f"dashboard server 'stop' at {host}:{DASHBOARD_PORT}"
        self.dashboard = Dashboard(host, CONNECT_TIMEOUT_S, STOP_TIMEOUT_S)
        self._receive: Any = None
        self._timestamp = -1.0
        self._fresh_at = 0.0

    @classmethod
    def from_manifest(cls, manifest: MonitorView, settings: SafetySettings) -> URWatch:
        """Raises:
            DeviceUnreachable: the manifest does not name the controller's address.
        """
        if manifest.emulator.launch:  # the address is the emulator's, chosen when it starts
            raise DeviceUnreachable(
                f"{manifest.path}: driver.host: not set, so the monitor cannot know where the "
                "controller is (with [emulator] launch = true the address is chosen at start: "
                "start the emulator yourself and name it here, with launch = false)")
        return cls(manifest.driver_settings.host, settings.device_timeout_ms / 1e3)

    def connect(self) -> None:
        try:
            self.dashboard.connect()
            remote = self.dashboard.ask("is in remote control")
        except DashboardError as error:
            raise DeviceUnreachable(f"{error}; check host in the manifest and that the "
                                    "dashboard server is enabled") from error
        if remote.lower() != "true":
            self.dashboard.close()
            raise DeviceUnreachable(
                f"the controller at {self.host} is not in remote control ({remote!r}): its "
                "dashboard server may refuse 'stop', and a stop path that may be refused is no "
                "stop path; switch the arm to Remote Control on the teach pendant")
        _reachable(self.host, RTDE_PORT, "RTDE server", CONNECT_TIMEOUT_S)
        self._open_receive()

    def _open_receive(self) -> None:
        import rtde_receive  # here: the vendor library loads only for a UR cell

        try:
            self._receive = rtde_receive.RTDEReceiveInterface(self.host, -1.0, VARIABLES)
        except RuntimeError as error:
            raise DeviceUnreachable(f"ur_rtde could not open an RTDE receive session at "
                                    f"{self.host}:{RTDE_PORT}: {error}") from error
        self._timestamp, self._fresh_at = -1.0, time.monotonic()

    def sample(self) -> Sample:
        receive = self._receive
        if receive is None or not receive.isConnected():
            raise DeviceLost(f"the RTDE session to {self.host} is closed")
        now = time.monotonic()
        timestamp = receive.getTimestamp()
        if timestamp != self._timestamp:
            self._timestamp, self._fresh_at = timestamp, now
        elif now - self._fresh_at > self.device_timeout_s:
            raise DeviceLost(f"no new RTDE data from {self.host} for "
                             f"{(now - self._fresh_at) * 1e3:.0f} ms")
        force = receive.getActualTCPForce()
        return Sample(q=tuple(receive.getActualQ()), qd=tuple(receive.getActualQd()),
                      force_n=math.sqrt(sum(f * f for f in force[:3])))

    def stop(self) -> StopResult:
        try:
            answer = self.dashboard.stop()
        except DashboardError as error:
            return StopResult(False, str(error))
        return StopResult(answer == STOPPED, f"dashboard answered {answer!r}")

    def probe(self) -> str | None:
        try:
            answer = self.dashboard.ask("running")
        except DashboardError:
            try:
                self.dashboard.connect()
                answer = self.dashboard.ask("running")
            except DashboardError as error:
                return str(error)
        if not answer.startswith("Program running:"):
            return f"the dashboard at {self.dashboard.address} answered {answer!r} to 'running'"
        return None

    def reconnect(self) -> bool:
        try:
            _reachable(self.host, RTDE_PORT, "RTDE server", self.device_timeout_s)
        except DeviceUnreachable:
            return False
        if self._receive is None:
            try:
                self._open_receive()
            except DeviceUnreachable:
                return False
            return True
        try:
            self._receive.reconnect()
        except RuntimeError:
            return False
        self._timestamp, self._fresh_at = -1.0, time.monotonic()
        return bool(self._receive.isConnected())

    def close(self) -> None:
        self.dashboard.close()
        receive, self._receive = self._receive, None
        if receive is not None:
            with contextlib.suppress(RuntimeError):  # a session the controller closed
                receive.disconnect()
            del receive


def _reachable(host: str, port: int, what: str, timeout_s: float) -> None:
    try:
        socket.create_connection((host, port), timeout=timeout_s).close()
    except OSError as error:
        raise DeviceUnreachable(f"cannot reach the UR {what} at {host}:{port} ({error}); check "
                                "host in the manifest, the network, and that the controller "
                                "is on") from error
