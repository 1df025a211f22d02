"""``warden safety MANIFEST`` and ``warden safety status``: the independent safety monitor.

    warden safety MANIFEST                 run the monitor for the cell MANIFEST describes
    warden safety status [MANIFEST]        ask the running monitor: alive, connected, watching?

Exit codes of the monitor: 0 stopped by SIGTERM or SIGINT; 2 it could not start (the message
names the key, or the device and what to check; nothing was commanded). Of ``status``: 0 the
monitor answered and is watching with its device and stop path connected and no limit breached;
1 it answered, not ok (the answer says why); 2 no monitor answered.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

EXIT_OK, EXIT_NOT_OK, EXIT_UNAVAILABLE = 0, 1, 2
STATUS = "status"


def add_commands(commands: Any) -> None:
    safety = commands.add_parser(
        "safety", help="the independent safety monitor, or its status",
        usage="warden safety MANIFEST [--log-format F] [--log-level L]\n"
              "       warden safety status [MANIFEST] [--socket PATH] [--timeout S]",
        description="`warden safety MANIFEST` runs the safety monitor for that cell: its own "
                    "connection to the device, its own stop path, warden's heartbeat. "
                    "`warden safety status [MANIFEST]` asks a running monitor whether it is "
                    "alive, connected and watching (exit 0), not ok (1), or absent (2).")
    safety.add_argument("target", nargs="+", metavar="MANIFEST|status",
                        help="a deployment manifest with a [safety] table, or 'status'")
    safety.add_argument("--socket", default="",
                        help="status: the monitor's status socket (default: the manifest's "
                             "safety.status_socket, else /run/warden-safety/status.sock)")
    safety.add_argument("--timeout", type=float, default=2.0, help="status: seconds to wait")
    safety.add_argument("--log-format", choices=("auto", "json", "console"), default="auto",
                        help="monitor: log lines on stderr (auto: JSON unless a terminal)")
    safety.add_argument("--log-level", default="INFO")
    safety.set_defaults(handler=safety_command)


def safety_command(args: argparse.Namespace) -> int:
    if args.target[0] == STATUS:
        if len(args.target) > 2:
            return _usage("status takes at most one manifest")
        return status_command(args.target[1] if len(args.target) == 2 else None, args)
    if len(args.target) != 1:
        return _usage("give one manifest (or 'status')")
    return run_command(args.target[0], args)


def run_command(manifest: str, args: argparse.Namespace) -> int:
    from kernel.safety.service import StartError, serve
    from kernel.shell.logging import configure_logging

    json_lines = args.log_format == "json" or (
        args.log_format == "auto" and not sys.stderr.isatty())
    try:
        configure_logging(args.log_level, json=json_lines)
    except ValueError as error:
        return _usage(f"--log-level: {error}")
    try:
        serve(manifest)
    except StartError as error:
        print(f"warden safety: {error}", file=sys.stderr)
        return EXIT_UNAVAILABLE
    return EXIT_OK


def status_command(manifest: str | None, args: argparse.Namespace) -> int:
    from kernel.safety.status import ask, socket_problem

    try:
        path = _status_path(manifest, args.socket)
    except ValueError as error:
        print(f"warden safety: {error}", file=sys.stderr)
        return EXIT_UNAVAILABLE
    try:
        answer = ask(path, args.timeout)
    except PermissionError:
        print(f"warden safety: {path}: permission denied (only the monitor's group may ask)",
              file=sys.stderr)
        return EXIT_UNAVAILABLE
    except OSError as error:
        print(f"warden safety: no safety monitor answers: {socket_problem(path, error)} (is "
              "`warden safety MANIFEST` running with the same [safety] status_socket?)",
              file=sys.stderr)
        return EXIT_UNAVAILABLE
    except ValueError as error:
        print(f"warden safety: {path}: no safety monitor answers ({error})", file=sys.stderr)
        return EXIT_UNAVAILABLE
    print(json.dumps(answer, indent=1))
    if not answer.get("ok"):
        problems = "; ".join(answer.get("problems") or ["not ok"])
        print(f"warden safety: not ok: {problems}", file=sys.stderr)
        return EXIT_NOT_OK
    return EXIT_OK


def _status_path(manifest: str | None, socket: str) -> Path:
    """Raises:
        ValueError: the manifest cannot be read, or has no [safety] table.
    """
    from kernel.safety.settings import SafetySettings
    from kernel.safety.view import read_view

    if socket:
        return Path(socket)
    if manifest is None:
        return SafetySettings().status_path
    settings = read_view(manifest).safety
    if settings is None:
        raise ValueError(f"{manifest}: safety: no [safety] table")
    return settings.status_path


def _usage(message: str) -> int:
    print(f"warden safety: {message}", file=sys.stderr)
    return EXIT_UNAVAILABLE
