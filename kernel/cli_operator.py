"""``warden operator status|takeover|release|accept-recovery|stop|reset [MANIFEST]``: a human's
authority over a running ``warden run``, through its operator socket (kernel/shell/operator.py).

The socket is ``--socket`` if given, else the manifest's ``[operator] socket`` (the manifest the
run was started with), else the service's runtime directory. Exit codes: 0 the command was
granted (the core decided it), 1 refused (by the group check, or by the core: the answer and
stderr say why), 2 no warden answers at the socket, or the manifest cannot be read.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import socket
import sys
from pathlib import Path
from typing import Any

from kernel.shell.operator import OperatorCommand, socket_path

EXIT_OK, EXIT_REFUSED, EXIT_UNREACHABLE = 0, 1, 2


def add_commands(commands: Any) -> None:
    operator = commands.add_parser(
        "operator", help="take over, release, recover or stop a running warden",
        description="Send one command to the operator socket of a running `warden run`. "
                    "Exit 0 when granted, 1 when refused (by the group check or by the core; "
                    "the answer says why), 2 when no warden answers at the socket.")
    operator.add_argument("command", choices=[c.value for c in OperatorCommand])
    operator.add_argument("manifest", nargs="?", metavar="MANIFEST",
                          help="the run's manifest: its [operator] socket is the one to use")
    operator.add_argument("--socket", default="",
                          help="the operator socket (default: the manifest's operator.socket, "
                               "else $RUNTIME_DIRECTORY/operator.sock, else "
                               "/run/warden/operator.sock)")
    operator.add_argument("--timeout", type=float, default=5.0, help="seconds to wait")
    operator.set_defaults(handler=operator_command)


def operator_command(args: argparse.Namespace) -> int:
    try:
        path = _socket(args.manifest, args.socket)
    except ValueError as error:
        print(f"warden: {error}", file=sys.stderr)
        return EXIT_UNREACHABLE
    try:
        answer = send(str(path), args.command, args.timeout)
    except PermissionError:
        print(f"warden: {path}: permission denied: only the operator group may command "
              "the arm", file=sys.stderr)
        return EXIT_UNREACHABLE
    except (OSError, ValueError) as error:
        print(f"warden: {path}: no warden answers here ({error})", file=sys.stderr)
        return EXIT_UNREACHABLE
    print(json.dumps(answer, indent=1))
    if not answer.get("ok"):
        print(f"warden: {args.command}: {answer.get('error', 'refused')}", file=sys.stderr)
        return EXIT_REFUSED
    if args.command == OperatorCommand.TAKEOVER:
        if answer.get("took_over"):
            print(f"takeover: the human has the arm, {answer['latency_ms']} ms after the "
                  "command arrived", file=sys.stderr)
        else:
            print("takeover: granted, but no tick owned by the human yet (check the fallback "
                  "state above)", file=sys.stderr)
    return EXIT_OK


def _socket(manifest: str | None, socket: str) -> Path:
    """Raises:
        ValueError: the manifest cannot be read (the message names the file and the key).
    """
    from kernel.manifest import load_manifest

    if socket or manifest is None:
        return socket_path(socket)
    # Only the socket: an operator need not be able to read the policy link's token.
    return socket_path(load_manifest(manifest, credentials=False).operator.socket)


def send(path: str, command: str, timeout_s: float) -> dict[str, Any]:
    """One request, one answer.

    Raises:
        OSError: nothing listens at ``path`` (PermissionError: not allowed to connect).
        ValueError: the answer is not one JSON object.
    """
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout_s)
        sock.connect(path)
        # A server past its bound for this uid answers and closes without reading: the answer
        # is still there to read.
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):
            sock.sendall(json.dumps({"command": command}).encode() + b"\n")
        data = b""
        while not data.endswith(b"\n"):
            chunk = sock.recv(65536)
            if not chunk:
                break
            data += chunk
    answer = json.loads(data)
    if not isinstance(answer, dict):
        raise ValueError("the answer is not a JSON object")
    return answer
