"""The dashboard server (port 29999) and the script port (30003) of the emulated controller.

Dashboard: one welcome line, then one answer line per command line, with the texts of the UR
dashboard server manual for the commands ur_rtde sends ("PolyscopeVersion", "get serial
number", "is in remote control", "stop", ...); "stop" answers once the arm has decelerated and
the program has ended (:mod:`stubs.ur_controller.program_stop`). Script port: URScript programs
arrive as text ("def name(): ... end"); a complete ``rtde_control`` program starts the control
script.
"""

from __future__ import annotations

import contextlib
import socket
import sys
from collections.abc import Callable
from typing import Protocol

from stubs.ur_controller.status import ControllerStatus, RuntimeState

WELCOME = "Connected: Universal Robots Dashboard Server"
SERIAL_NUMBER = "20235500001"
MAX_PROGRAM_BYTES = 1 << 20


class Controller(Protocol):
    status: ControllerStatus

    def software_version(self) -> str: ...

    def stop_program(self) -> bool: ...

    def load_program(self, name: str, text: str) -> None: ...

    def unlock_protective_stop(self) -> bool: ...


def serve_dashboard(sock: socket.socket, controller: Controller) -> None:
    with sock, sock.makefile("rwb", buffering=0) as stream, contextlib.suppress(OSError):
        stream.write((WELCOME + "\n").encode())
        for raw in stream:  # until the client hangs up (or resets: that ends it too)
            command = raw.decode(errors="replace").strip()
            if not command:
                continue
            stream.write((answer(controller, command) + "\n").encode())
            if command == "quit":
                return


def answer(controller: Controller, command: str) -> str:
    """The dashboard server's reply to one command line."""
    status = controller.status
    replies: dict[str, Callable[[], str]] = {
        "PolyscopeVersion": lambda: f"URSoftware {controller.software_version()} (Mar 22 2022)",
        "get serial number": lambda: SERIAL_NUMBER,
        "is in remote control": lambda: "true",
        "stop": lambda: "Stopped" if controller.stop_program() else "Failed to execute: stop",
        "running": lambda: f"Program running: {str(status.program_running).lower()}",
        "programState": lambda: f"{_program_state(status)} rtde_control",
        "robotmode": lambda: f"Robotmode: {status.robot_mode.name}",
        "safetymode": lambda: f"Safetymode: {status.safety_mode.name}",
        "safetystatus": lambda: f"Safetystatus: {status.safety_mode.name}",
        "get robot model": lambda: "UR5",
        "unlock protective stop": lambda: _unlock(controller),
        "close safety popup": lambda: "closing safety popup",
        "close popup": lambda: "closing popup",
        "quit": lambda: "Disconnected",
    }
    reply = replies.get(command)
    return reply() if reply is not None else f"Could not understand: '{command}'"


def _program_state(status: ControllerStatus) -> str:
    return "PLAYING" if status.runtime_state is RuntimeState.PLAYING else "STOPPED"


def _unlock(controller: Controller) -> str:
    if controller.unlock_protective_stop():
        return "Protective stop releasing"
    return "Cannot unlock protective stop: the robot is not in a protective stop"


def serve_script_port(sock: socket.socket, controller: Controller) -> None:
    """Collect programs sent to the script port; the real port never answers on it either."""
    pending = ""
    with sock, contextlib.suppress(OSError):
        while chunk := sock.recv(65536):
            pending += chunk.decode(errors="replace")
            pending = _run_complete_programs(pending, controller)
            if len(pending) > MAX_PROGRAM_BYTES:
                print("ur_controller: script port overflow, dropping input", file=sys.stderr)
                pending = ""


def _run_complete_programs(pending: str, controller: Controller) -> str:
    """Start every complete ``def name(): ... end`` program in ``pending``; return the rest."""
    while True:
        start = pending.find("def ")
        end = pending.find("\nend\n", start)
        if start < 0 or end < 0:
            return pending
        program = pending[start : end + len("\nend\n")]
        name = program[len("def ") : program.find("(")].strip()
        controller.load_program(name, program)
        pending = pending[end + len("\nend\n") :]
