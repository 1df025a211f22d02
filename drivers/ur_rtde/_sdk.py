"""The parts of ur_rtde 1.6.5 this driver uses, as typing Protocols, and where they come from.

Facts that shape every call site (measured, see shared notes "ur_rtde 1.6.5"):

- Constructors and destructors hold the GIL for their whole run (the destructor sleeps 0.5 s):
  the process freezes meanwhile. Build and drop them on the device thread, never in a loop.
- Methods release the GIL. Blocking commands (stopJ, servoStop, stopScript, reuploadScript)
  wait for the control script's "done" for up to 300 s on a dead link: call them only when
  the data stream is known to be fresh, and always through a deadline.
- ``RTDEControlInterface`` reconnects on its own receive thread when its socket fails, and
  inside any command that fails to write. If the controller answers while that runs, the
  object ends up with two receive threads and the process crashes (measured: up to 70 % of
  runs when the emulator came back within milliseconds; none when it came back 0.5 s later).
  The driver cannot switch this off. It checks ``isConnected()`` before every command, stops
  commanding at the first sign of loss, and calls ``reconnect()`` itself only from connect().
- ``RTDEIOInterface`` (tool and standard outputs) has no receive thread: it writes packages
  and never reads, so it cannot tell that the controller closed its session. ``isConnected()``
  stays True; the first write after the close is lost silently, later ones raise RuntimeError
  (broken pipe). Its destructor sends RTDE "pause" and waits for the answer: on a session the
  controller has closed that throws inside the destructor and std::terminate kills the
  process (measured, every time). So the link renews it on every connect, and releases it
  only through a ``disconnect()`` that succeeded; see ``link.release_io``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol


class ReceiveInterface(Protocol):
    """``rtde_receive.RTDEReceiveInterface``."""

    def isConnected(self) -> bool: ...

    def reconnect(self) -> bool: ...

    def disconnect(self) -> None: ...

    def getTimestamp(self) -> float: ...

    def getActualQ(self) -> list[float]: ...

    def getActualQd(self) -> list[float]: ...

    def getActualTCPForce(self) -> list[float]: ...

    def getRobotMode(self) -> int: ...

    def getSafetyStatusBits(self) -> int: ...

    def getRuntimeState(self) -> int: ...

    def getSpeedScaling(self) -> float: ...

    def getTargetSpeedFraction(self) -> float: ...

    def getStandardAnalogInput0(self) -> float: ...

    def getStandardAnalogInput1(self) -> float: ...

    def getActualDigitalOutputBits(self) -> int: ...


class ControlInterface(Protocol):
    """``rtde_control.RTDEControlInterface`` (uploads and talks to the ``rtde_control`` script)."""

    def isConnected(self) -> bool: ...

    def reconnect(self) -> bool: ...

    def disconnect(self) -> None: ...

    def isProgramRunning(self) -> bool: ...

    def reuploadScript(self) -> bool: ...

    def stopScript(self) -> None: ...

    def servoJ(self, q: Sequence[float], speed: float, acceleration: float, time: float,
               lookahead_time: float, gain: float) -> bool: ...

    def speedJ(self, qd: Sequence[float], acceleration: float, time: float) -> bool: ...

    def stopJ(self, a: float, asynchronous: bool) -> None: ...

    def servoStop(self, a: float) -> bool: ...

    def speedStop(self, a: float) -> bool: ...

    def setWatchdog(self, min_frequency: float) -> bool: ...

    def kickWatchdog(self) -> bool: ...


class IOInterface(Protocol):
    """``rtde_io.RTDEIOInterface`` (16 input recipes; writes only, fire-and-forget)."""

    def isConnected(self) -> bool: ...

    def reconnect(self) -> bool: ...

    def disconnect(self) -> None: ...

    def setToolDigitalOut(self, output_id: int, signal_level: bool) -> bool: ...


def open_receive(host: str, frequency_hz: float, variables: list[str]) -> ReceiveInterface:
    """Connect an RTDE receive session (blocks with the GIL held until the first package)."""
    import rtde_receive  # imported on first use: a robot PC without ur_rtde runs other drivers

    return rtde_receive.RTDEReceiveInterface(host, frequency_hz, variables)


def open_control(host: str) -> ControlInterface:
    """Connect dashboard, script port and RTDE; upload ``rtde_control`` and wait for it to run.

    The controller picks the frequency (500 Hz on e-Series); the script is uploaded by the
    library (FLAG_UPLOAD_SCRIPT), which stops any program already running first.
    """
    import rtde_control

    flags = rtde_control.RTDEControlInterface.Flags.FLAG_UPLOAD_SCRIPT
    return rtde_control.RTDEControlInterface(host, -1.0, flags)


def open_io(host: str) -> IOInterface:
    """Connect an RTDE IO session: its input recipes, then a 100 ms wait (GIL held)."""
    import rtde_io

    return rtde_io.RTDEIOInterface(host)
