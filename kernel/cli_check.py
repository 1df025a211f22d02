"""``warden check MANIFEST``: bring the device up, watch it hold, compare it with the manifest,
never move it (kernel/app/check.py says how), and print the readiness table.

Exit codes: 0 no check is NOT READY (NOT EXERCISED rows name what check cannot try); 1 some check
is NOT READY; 2 invalid input, nothing started: a manifest that does not load (file and key
named), a signature that does not verify, ``--seconds`` out of range, or a device that cannot be
reached or identified at connect (the device and what to check named).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import msgspec

from drivers.readiness import CheckVerdict
from kernel.app.check import SECONDS_RANGE, Report, load_checked, run_check
from kernel.cli_run import configure_logging, preflight
from kernel.shell.device_lock import holding
from kernel.signing import DEFAULT_KEYS_DIR

TABLE_WIDTH = 160
VERDICT_STYLES = {CheckVerdict.READY: "green", CheckVerdict.NOT_READY: "bold red",
                  CheckVerdict.NOT_EXERCISED: "yellow"}


def add_commands(commands: Any) -> None:
    check = commands.add_parser(
        "check", help="bring the device up without moving it and compare it with the manifest",
        description="Verify the manifest's signature, connect, configure and activate the "
                    "device as a run does, watch it hold for a few seconds, compare its modes, "
                    "limits and calibration with the manifest, then deactivate and close it. "
                    "No motion command is ever sent.")
    check.add_argument("manifest")
    check.add_argument("--keys", default=str(DEFAULT_KEYS_DIR),
                       help=f"trusted public keys (default {DEFAULT_KEYS_DIR})")
    check.add_argument("--seconds", type=float, default=3.0,
                       help=f"how long to watch the device hold ({SECONDS_RANGE[0]:g} to "
                            f"{SECONDS_RANGE[1]:g}; default 3)")
    check.add_argument("--json", dest="json_out", metavar="FILE",
                       help="also write the findings as JSON to FILE ('-' for stdout)")
    check.add_argument("--log-format", choices=("auto", "json", "console"), default="auto")
    check.add_argument("--log-level", default="WARNING")
    check.set_defaults(handler=check_command)


def check_command(args: argparse.Namespace) -> int:
    configure_logging(args)
    manifest, signature = load_checked(Path(args.manifest), Path(args.keys))
    preflight(manifest)
    # check enables a CANopen bus's drives: it excludes a running warden like another run.
    with holding(manifest, "warden check"):
        report = run_check(manifest, signature, args.seconds)
    _render(report, to_stderr=args.json_out == "-")
    if args.json_out:
        _write_json(report, args.json_out)
    return report.exit_code


def _render(report: Report, to_stderr: bool) -> None:
    from rich.console import Console
    from rich.table import Table

    counts = {verdict: sum(f.verdict is verdict for f in report.findings)
              for verdict in CheckVerdict}
    table = Table(title=f"warden check {report.manifest.path} (driver {report.device}): "
                        f"{counts[CheckVerdict.READY]} ready, "
                        f"{counts[CheckVerdict.NOT_READY]} not ready, "
                        f"{counts[CheckVerdict.NOT_EXERCISED]} not exercised; "
                        "no motion command sent",
                  show_lines=True)
    for column in ("check", "expected", "measured", "verdict", "why"):
        table.add_column(column, overflow="fold")
    for finding in report.findings:
        table.add_row(finding.name, finding.expected, finding.measured,
                      f"[{VERDICT_STYLES[finding.verdict]}]{finding.verdict}[/]", finding.reason)
    console = Console(stderr=to_stderr)
    if not console.is_terminal:
        console.width = TABLE_WIDTH  # a log file or pipe: wide enough for the measured values
    console.print(table)


def _write_json(report: Report, json_out: str) -> None:
    document = {"manifest": str(report.manifest.path), "name": report.manifest.name,
                "driver": report.device, "digest": report.manifest.digest,
                "signer": report.manifest.signer, "exit_code": report.exit_code,
                "findings": report.findings}
    data = msgspec.json.format(msgspec.json.encode(document), indent=1)
    if json_out == "-":
        sys.stdout.buffer.write(data + b"\n")
        sys.stdout.flush()
    else:
        Path(json_out).write_bytes(data + b"\n")
