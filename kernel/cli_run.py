"""``warden run`` and ``warden serve-policy``."""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

from kernel.manifest import ClockKind, Manifest, ManifestError, load_manifest
from kernel.scenario.bounds import CYCLES_MAX

REPO = Path(__file__).resolve().parents[1]
DEFAULT_MANIFEST = REPO / "manifests" / "sim-ur5e.toml"


def add_commands(commands: Any) -> None:
    run = commands.add_parser(
        "run", help="run the assembly cell described by a manifest",
        description="Run the assembly cycle: plant or driver, policy server, runtime.")
    run.add_argument("manifest", nargs="?", default=str(DEFAULT_MANIFEST),
                     help="deployment manifest (TOML); default: the simulated UR5e cell")
    run.add_argument("--cycles", type=int, help="assembly cycles to run (overrides the manifest)")
    run.add_argument("--clock", choices=[c.value for c in ClockKind],
                     help="wall: real time with the policy server on loopback; "
                          "virtual: lockstep, fast and deterministic")
    run.add_argument("--json", dest="json_out", metavar="FILE",
                     help="also write the summary as JSON to FILE ('-' for stdout)")
    run.add_argument("--journal-dir", help="where run directories go (default: the manifest's)")
    run.add_argument("--no-journal", action="store_true", help="do not record a journal")
    run.add_argument("--keys", metavar="DIR",
                     help="refuse a manifest not signed by a key in DIR; the signature is checked "
                          "in this process on the very bytes that then run (the systemd unit "
                          "passes /etc/warden/keys)")
    run.add_argument("--await-confirmation", action="store_true",
                     help="hold before anything starts (no device opened) until a member of the "
                          "operator group runs `warden operator confirm`; the shipped unit "
                          "passes it, so neither a boot nor a restart moves the arm")
    run.add_argument("--log-format", choices=("auto", "json", "console"), default="auto",
                     help="log lines on stderr: JSON (auto when stderr is not a terminal, e.g. "
                          "under systemd) or plain console lines")
    run.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING, ERROR")
    run.set_defaults(handler=run_command)
    serve = commands.add_parser(
        "serve-policy", help="run the reference policy server (scripted insertion policy)",
        description="Arguments are those of `python -m stubs.policy_server --help`.",
        add_help=False)
    serve.add_argument("server_args", nargs=argparse.REMAINDER)
    serve.set_defaults(handler=serve_command)


EXIT_RECORD_FAILED = 3
"""The run's record (journal, decision log) could not be written: the core stopped the arm
and the run ended early (docs/operations.md, exit codes)."""


def run_command(args: argparse.Namespace) -> int:
    configure_logging(args)
    manifest = checked_manifest(args.manifest, args.cycles, args.clock, args.keys)
    journal_dir = journal_directory(manifest, args.journal_dir, args.no_journal)
    if args.await_confirmation:  # a held start (kernel/app/held.py): nothing moves before
        from kernel.app.held import HeldStopped, hold_until_confirmed

        try:
            hold_until_confirmed(manifest)
        except HeldStopped as stopped:
            print(f"warden: {stopped}", file=sys.stderr)
            return stopped.exit_code
    summary = asyncio.run(_run(manifest, journal_dir)) if manifest.cell.clock is (
        ClockKind.VIRTUAL) else run_wall(manifest, journal_dir)
    output(summary, args.json_out)
    if report_record_failure(summary):
        return EXIT_RECORD_FAILED
    cycles = summary["cycles"]
    return 0 if cycles["verified"] == cycles["attempted"] == manifest.cell.cycles else 1


def journal_directory(manifest: Manifest, override: str | None,
                      disabled: bool = False) -> Path | None:
    """Where this run's directory goes, checked before any device, emulator or server starts.

    Raises:
        ManifestError: it cannot hold run journals (/dev/null, /proc, a read-only or full file
            system, ...), naming the option or the manifest key and why.
    """
    from kernel.shell.record_file import journal_directory_problem

    if disabled or not manifest.journal.enabled:
        return None
    key = "--journal-dir" if override else f"{manifest.path}: journal.directory"
    path = Path(override or manifest.journal.directory)
    problem = journal_directory_problem(path)
    if problem is not None:
        raise ManifestError(f"{key}: {path}: cannot keep run journals there: {problem}")
    return path


def report_record_failure(summary: dict[str, Any]) -> bool:
    """Say on stderr why a run whose record failed ended, what was lost and where the rest
    is (stderr may be the only record left: under systemd it lands in the system journal).
    True if the record failed."""
    journal = summary.get("journal") or {}
    if not journal.get("error"):
        return False
    tail = {True: "the rest of the run (the failure, the stop, the last ticks) was written "
                  "into the space the files keep reserved",
            False: "the rest of the run did not fit into the reserved space and was not "
                   "written: both files end before the failure",
            None: "the failure came after the control loop had ended"}[journal["tail_written"]]
    lines = [f"the run's record could not be written ({journal['error']})",
             "the core stopped the arm (RECORDER_FAILED) and the run ended"
             if journal["core_told"] else "the arm was held and the device closed as at the "
             "end of any run",
             f"{journal['gaps']} records lost; {tail}",
             f"run directory: {journal['directory']}"
             + (f" (summary.json {journal['summary_file']})" if "summary_file" in journal
                else "")]
    for line in lines:
        print(f"warden: {line}", file=sys.stderr)
    return True


def configure_logging(args: argparse.Namespace) -> None:
    """Structured log lines go to stderr (stdout may carry the JSON summary)."""
    from kernel.shell.logging import configure_logging

    json_lines = args.log_format == "json" or (
        args.log_format == "auto" and not sys.stderr.isatty())
    try:
        configure_logging(args.log_level, json=json_lines)
    except ValueError as error:
        raise ManifestError(f"--log-level: {error}") from None


def checked_manifest(path: str | Path, cycles: int | None = None,
                     clock: str | None = None, keys: str | Path | None = None) -> Manifest:
    """The manifest ``warden run`` runs, with the command line's overrides, checked as far as
    anything can be checked before a device, an emulator or a server starts. (The property
    tests of ``tests/fuzz`` drive this: running the cell itself is not a loader's business.)
    With ``keys``, the file is read once and its signature verified on those bytes, which are
    the ones parsed (a file swapped after the check is never run).

    Raises:
        ManifestError: naming the file (or the option) and the key, or why the signature does
            not verify; the CLI exits 2.
    """
    manifest = _with_overrides(_loaded(Path(path), keys), cycles, clock)
    preflight(manifest)
    return manifest


def _loaded(path: Path, keys: str | Path | None) -> Manifest:
    if keys is None:
        return load_manifest(path)
    from kernel import signing

    try:
        verified = signing.verify(path, keys)
    except signing.SignatureError as error:
        raise ManifestError(f"{error} (--keys {keys})") from None
    return load_manifest(path, content=verified.content, signer=verified.key_id)


def preflight(manifest: Manifest) -> None:
    """Every check that needs more than the manifest's own keys, made before any device,
    emulator or server starts: the task's layout against the robot, the clock against the
    driver.

    Raises:
        ManifestError: naming the file and the key.
    """
    from kernel.app.task import check_task

    check_task(manifest)
    if manifest.cell.clock is ClockKind.VIRTUAL and manifest.driver_name != "sim":
        raise ManifestError(f"{manifest.path}: cell.clock: a virtual clock needs the in-process "
                            f"plant (driver 'sim'); {manifest.driver_name!r} runs in real time")


def _with_overrides(manifest: Manifest, cycles: int | None, clock: str | None) -> Manifest:
    cell = manifest.cell
    if cycles is not None:
        if not 1 <= cycles <= CYCLES_MAX:
            raise ManifestError(f"--cycles: must be 1 to {CYCLES_MAX}, got {cycles}")
        cell = dataclasses.replace(cell, cycles=cycles)
    if clock is not None:
        cell = dataclasses.replace(cell, clock=ClockKind(clock))
    return dataclasses.replace(manifest, cell=cell)


async def _run(manifest: Manifest, journal_dir: Path | None) -> dict[str, Any]:
    from kernel.app.lockstep import run_lockstep
    from kernel.app.report import CycleProgress

    with CycleProgress(manifest.cell.cycles) as progress:
        return await run_lockstep(manifest, journal_dir, progress)


def run_wall(manifest: Manifest, journal_dir: Path | None, hook: Any = None) -> dict[str, Any]:
    """The cell on the wall clock (``hook``: called after each tick, True ends the run)."""
    from kernel.app.live import run_live
    from kernel.app.report import CycleProgress
    from kernel.shell.loop import run

    async def main() -> dict[str, Any]:
        with CycleProgress(manifest.cell.cycles) as progress:
            return await run_live(manifest, journal_dir, progress, hook)

    return run(main())


def output(summary: dict[str, Any], json_out: str | None) -> None:
    from rich.console import Console

    from kernel.app.report import render_summary

    # With the JSON on stdout, the table goes to stderr so stdout stays machine-readable.
    render_summary(summary, Console(stderr=json_out == "-"))
    if json_out == "-":
        print(json.dumps(summary, indent=1, default=str))
    elif json_out:
        try:
            Path(json_out).write_text(json.dumps(summary, indent=1, default=str))
        except OSError as error:  # after the run: say so, the table above has the summary
            print(f"warden: --json: cannot write {json_out}: {error.strerror or error}",
                  file=sys.stderr)


def serve_command(args: argparse.Namespace) -> int:
    from kernel.app import standins

    return int(standins.load(standins.POLICIES, "serve")(args.server_args))


__all__ = ["add_commands"]

