"""The monitor's watch on the simulated cell (driver ``sim``): the world's test-only control port.

The simulated plant lives inside warden's process, stepped by warden's control loop; the
simulated world serves a loopback control port (``[safety] sim_port``) that answers the plant's
ground truth (joints, speeds, wrist wrench) and engages a brake: from then on the plant holds
where it is and ignores warden's commands, as a braked arm would. The protocol is one JSON
object per line each way (``{"fault": "ground_truth"}`` → ``{"ok": true, "q": [...], ...}``).

What this cannot show: warden hanging. The world steps only when warden's loop ticks, so a
stopped warden freezes the plant (and its control port with it): nothing moves, and the
monitor sees its device stop answering. The UR cell, whose emulator is its own process, is
where a hang is tested.
"""

from __future__ import annotations

import contextlib
import json
import math
import socket
from typing import Any

from kernel.safety.checks import Sample
from kernel.safety.settings import SafetySettings
from kernel.safety.view import MonitorView
from kernel.safety.watch import DeviceLost, DeviceUnreachable, StopResult

HOST = "127.0.0.1"
STOP_TIMEOUT_S = 1.0


class SimWorldWatch:
    can_stop = True
    lives_in_warden = True

    def __init__(self, port: int, timeout_s: float) -> None:
        self.port, self.timeout_s = port, timeout_s
        self.description = f"simulated world's control port at {HOST}:{port}"
        self.stop_path = f"the simulated world's brake at {HOST}:{port}"
        self._sock: socket.socket | None = None
        self._reader: Any = None

    @classmethod
    def from_manifest(cls, manifest: MonitorView, settings: SafetySettings) -> SimWorldWatch:
        """Raises:
            DeviceUnreachable: no ``sim_port`` in the manifest.
        """
        if not settings.sim_port:
            raise DeviceUnreachable(f"{manifest.path}: safety.sim_port: not set; the simulated "
                                    "world serves its control port only where this names one")
        return cls(settings.sim_port, settings.device_timeout_ms / 1e3)

    def connect(self) -> None:
        try:
            self._open()
            self._request("ground_truth", self.timeout_s)
        except (OSError, ValueError) as error:
            self.close()
            raise DeviceUnreachable(
                f"cannot reach the simulated world's control port at {HOST}:{self.port} "
                f"({error}); start `warden run` with this manifest first (the world lives in "
                "its process) and check safety.sim_port") from error

    def sample(self) -> Sample:
        try:
            truth = self._request("ground_truth", self.timeout_s)
            wrench = truth.get("wrench") or [0.0] * 6
            return Sample(q=tuple(map(float, truth["q"])), qd=tuple(map(float, truth["qd"])),
                          force_n=math.sqrt(sum(float(f) ** 2 for f in wrench[:3])))
        except (OSError, ValueError, KeyError, TypeError) as error:
            self.close()
            raise DeviceLost(f"the simulated world at {HOST}:{self.port} does not answer "
                             f"({error})") from error

    def stop(self) -> StopResult:
        try:
            if self._sock is None:
                self._open()
            self._request("brake", STOP_TIMEOUT_S)
        except (OSError, ValueError) as error:
            self.close()
            return StopResult(False, f"brake not engaged: {error}")
        return StopResult(True, "brake engaged")

    def probe(self) -> str | None:
        return None  # every sample asks the same port the brake goes through

    def reconnect(self) -> bool:
        try:
            self._open()
        except OSError:
            return False
        return True

    def close(self) -> None:
        for closable in (self._reader, self._sock):
            if closable is not None:
                with contextlib.suppress(OSError):
                    closable.close()
        self._sock = self._reader = None

    def _open(self) -> None:
        self.close()
        self._sock = socket.create_connection((HOST, self.port), timeout=self.timeout_s)
        self._reader = self._sock.makefile("rb")

    def _request(self, name: str, timeout_s: float) -> dict[str, Any]:
        if self._sock is None:
            raise ConnectionError("not connected")
        self._sock.settimeout(timeout_s)
        self._sock.sendall(json.dumps({"fault": name}).encode() + b"\n")
        line = self._reader.readline(1 << 16)
        if not line:
            raise ConnectionError("the control port closed the connection")
        answer = json.loads(line)
        if not isinstance(answer, dict) or not answer.get("ok"):
            raise ValueError(f"{name!r} refused: {answer}")
        return answer
