"""A tiny line-JSON control port for injecting faults into an emulator process.

Each request is one JSON object per line: ``{"fault": "protective_stop", ...}``; each answer is
one JSON object per line: ``{"ok": true}`` (plus whatever a handler returns, for queries such
as ``ground_truth``) or ``{"ok": false, "error": "..."}``. Emulators register one handler per
name. This is test tooling, bound to loopback only.
"""

from __future__ import annotations

import json
import socket
import socketserver
import threading
from collections.abc import Callable, Mapping
from typing import Any

Handler = Callable[[dict[str, Any]], dict[str, Any] | None]


class FaultControlServer:
    def __init__(self, host: str, port: int, handlers: Mapping[str, Handler]) -> None:
        handlers = dict(handlers)

        class _Request(socketserver.StreamRequestHandler):
            def handle(self) -> None:
                for line in self.rfile:
                    self.wfile.write(_dispatch(handlers, line) + b"\n")

        socketserver.ThreadingTCPServer.allow_reuse_address = True
        self._server = socketserver.ThreadingTCPServer((host, port), _Request)
        self._server.daemon_threads = True
        self.address = self._server.server_address
        # A short poll interval keeps stop() from waiting out serve_forever's 0.5 s default.
        self._thread = threading.Thread(
            target=self._server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True
        )

    def start(self) -> FaultControlServer:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._server.shutdown()
        self._server.server_close()


def _dispatch(handlers: Mapping[str, Handler], line: bytes) -> bytes:
    try:
        request = json.loads(line)
        result = handlers[request["fault"]](request)
        answer: dict[str, Any] = {"ok": True, **(result if isinstance(result, dict) else {})}
    except KeyError as error:
        answer = {"ok": False, "error": f"unknown fault or missing field: {error}"}
    except Exception as error:  # a bad request must not kill the emulator
        answer = {"ok": False, "error": f"{type(error).__name__}: {error}"}
    return json.dumps(answer).encode()


def inject(
    address: tuple[str, int], fault: str, timeout_s: float = 2.0, **fields: Any
) -> dict[str, Any]:
    """Send one request; return the answer, raise if the emulator refused it."""
    with socket.create_connection(address, timeout=timeout_s) as conn:
        conn.sendall(json.dumps({"fault": fault, **fields}).encode() + b"\n")
        answer = json.loads(conn.makefile("rb").readline())
    if not answer.get("ok"):
        raise RuntimeError(f"fault {fault!r} refused: {answer.get('error')}")
    return answer
