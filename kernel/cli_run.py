"""``warden run`` and ``warden serve-policy``."""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import msgspec

from kernel.app.interrupt import EXIT_INTERRUPTED
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
        "serve-policy", help="serve the reference policy a manifest's cell expects",
        description="Serve, in the foreground until SIGINT or SIGTERM, exactly the reference "
                    "policy server `warden run` launches for MANIFEST (its offer, goal, latency "
                    "model, noise and seed), on --host and --port. A copy of the manifest with "
                    "`[policy] launch = false` and that host and port runs against it "
                    "(docs/operations.md, \"Running the policy server yourself\"). Prints "
                    "`READY {\"port\": N}` on stdout once it listens.")
    serve.add_argument("manifest", nargs="?", default=str(DEFAULT_MANIFEST),
                       help="the cell's manifest (TOML); default: the simulated UR5e cell")
    serve.add_argument("--host", help="address to listen on (default: the manifest's "
                                      "policy.host); not loopback only with --expose")
    serve.add_argument("--port", type=int, help="port to listen on, 0 … 65535 (default: the "
                                                "manifest's policy.port; 0 picks a free one)")
    serve.add_argument("--expose", action="store_true",
                       help="listen on a --host that is not loopback (the link has no "
                            "authentication)")
    serve.set_defaults(handler=serve_command)


EXIT_RECORD_FAILED = 3
"""The run's record (journal, decision log) could not be written: the core stopped the arm
and the run ended early (docs/operations.md, exit codes)."""


def run_command(args: argparse.Namespace) -> int:
    structured = configure_logging(args)
    manifest = checked_manifest(args.manifest, args.cycles, args.clock, args.keys)
    journal_dir = journal_directory(manifest, args.journal_dir, args.no_journal)
    from kernel.shell.device_lock import holding

    # One warden per device: before any connection, emulator or real-time priority, and before
    # a held start waits (a second service on the same device is refused at once).
    with holding(manifest, "warden run"):
        if args.await_confirmation:  # a held start (kernel/app/held.py): nothing moves before
            from kernel.app.held import HeldStopped, hold_until_confirmed

            try:
                hold_until_confirmed(manifest)
            except HeldStopped as stopped:
                print(f"warden: {stopped}", file=sys.stderr)
                return stopped.exit_code
        summary = asyncio.run(_run(manifest, journal_dir, structured)) if manifest.cell.clock is (
            ClockKind.VIRTUAL) else run_wall(manifest, journal_dir, structured=structured)
    output(summary, args.json_out, structured)
    if report_record_failure(summary):
        return EXIT_RECORD_FAILED
    if summary.get("interrupted"):
        report_interrupt(summary, manifest.cell.cycles, journal_dir is not None)
        return EXIT_INTERRUPTED[summary["interrupted"]]
    cycles = summary["cycles"]
    return 0 if cycles["verified"] == cycles["attempted"] == manifest.cell.cycles else 1


def report_interrupt(summary: dict[str, Any], planned: int, journaled: bool) -> None:
    """Say on stderr that a signal ended the run, where, and that the arm was left held."""
    cycles, signal_name = summary["cycles"], summary["interrupted"]
    cut = summary["cycle_cut_short"]
    if cut is not None:
        where = (f"during cycle {cut} of {planned}; the run ended there: the arm "
                 "was held and the device closed")
    elif not summary["loop"]["ticks"]:
        where = "before the first tick; the run ended there: nothing moved, the device was closed"
    else:
        where = "after its last cycle: the arm was held and the device closed"
    directory = summary["journal"]["directory"]
    lines = [f"interrupted by {signal_name} {where}",
             f"{cycles['verified']} of {cycles['attempted']} cycles attempted were verified"
             + (" (the interrupted one counts as attempted, not verified)"
                if cut is not None else ""),
             f"journal closed: {directory}/journal.jsonl replays the run" if directory != "-"
             else "no run directory kept: nothing was recorded" if journaled
             else "no journal was kept (journal disabled)"]
    for line in lines:
        print(f"warden: {line}", file=sys.stderr)


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
    """Say on stderr why a run whose record failed ended, what each file holds, what was lost
    and where the rest is (stderr may be the only record left: under systemd it lands in the
    system journal). Every statement is what the recorder found when it wrote, never what it
    meant to write. True if the record failed."""
    journal = summary.get("journal") or {}
    if not journal.get("error"):
        return False
    lines = [f"the run's record could not be written ({journal['error']})",
             "the core stopped the arm (RECORDER_FAILED) and the run ended"
             if journal["core_told"] else "the arm was held and the device closed as at the "
             "end of any run"]
    lines += [_file_held(name, held) for name, held in (journal.get("files") or {}).items()]
    lines += [_tail_fate(journal), f"{journal['gaps']} records lost",
              f"run directory: {journal['directory']}"
              + (f" (summary.json {journal['summary_file']})" if "summary_file" in journal
                 else "")]
    for line in lines:
        print(f"warden: {line}", file=sys.stderr)
    return True


def _file_held(name: str, held: dict[str, Any]) -> str:
    end = held["ends_at_t_ms"]
    text = f"{name}: {held['lines']} lines written" + (
        f", the last at t={end:.3f} ms" if end is not None else ", no record of the run")
    if held["sync_error"]:
        text += (f"; its sync at close failed ({held['sync_error']}): the disk may hold "
                 "fewer")
    return text


def _tail_fate(journal: dict[str, Any]) -> str:
    written = journal["tail_written"]
    if written is None:
        return "the failure came after the control loop had ended"
    if written:
        return ("the rest of the run (the failure, the stop, the last ticks) was written into "
                "the space the files keep reserved")
    return (f"the rest of the run (the failure, the stop, the last ticks) was NOT written: "
            f"{journal['tail_error']}; the files end where said above")


def configure_logging(args: argparse.Namespace) -> bool:
    """Structured log lines go to stderr (stdout may carry the JSON summary). True when they
    are JSON lines: the run's progress is then log lines too."""
    from kernel.shell.logging import configure_logging

    json_lines = args.log_format == "json" or (
        args.log_format == "auto" and not sys.stderr.isatty())
    try:
        configure_logging(args.log_level, json=json_lines)
    except ValueError as error:
        raise ManifestError(f"--log-level: {error}") from None
    return json_lines


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
        cell = msgspec.structs.replace(cell, cycles=cycles)
    if clock is not None:
        cell = msgspec.structs.replace(cell, clock=ClockKind(clock))
        if cell.clock is ClockKind.VIRTUAL and manifest.cameras:
            raise ManifestError(f"--clock virtual: {manifest.path} has [[cameras]], which see "
                                "the cell on the wall clock")
        if cell.clock is ClockKind.VIRTUAL and manifest.metrics is not None:
            raise ManifestError(f"--clock virtual: {manifest.path} has [metrics], which a "
                                "virtual-clock run does not serve")
    return dataclasses.replace(manifest, cell=cell)


async def _run(manifest: Manifest, journal_dir: Path | None,
               structured: bool = False) -> dict[str, Any]:
    from kernel.app.lockstep import run_lockstep
    from kernel.app.report import CycleProgress

    with CycleProgress(manifest.cell.cycles, structured=structured) as progress:
        return await run_lockstep(manifest, journal_dir, progress)


def run_wall(manifest: Manifest, journal_dir: Path | None, hook: Any = None, *,
             structured: bool = False) -> dict[str, Any]:
    """The cell on the wall clock (``hook``: called after each tick, True ends the run;
    ``structured``: progress as JSON log lines)."""
    from kernel.app.live import run_live
    from kernel.app.report import CycleProgress
    from kernel.shell.loop import run

    async def main() -> dict[str, Any]:
        with CycleProgress(manifest.cell.cycles, structured=structured) as progress:
            return await run_live(manifest, journal_dir, progress, hook)

    return run(main())


def output(summary: dict[str, Any], json_out: str | None, structured: bool = False) -> None:
    from rich.console import Console

    from kernel.app.report import render_summary

    # With the JSON on stdout, the table goes to stderr so stdout stays machine-readable;
    # unless stderr carries JSON log lines only: then the JSON on stdout is the summary.
    if not (json_out == "-" and structured):
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
    """``warden serve-policy``: the reference server a manifest's cell expects, in the
    foreground (exit 0 on SIGINT or SIGTERM, 2 for invalid input)."""
    from kernel.app import standins
    from kernel.app.compose import cell_context
    from kernel.manifest import is_loopback

    manifest = checked_manifest(args.manifest)
    host = args.host if args.host is not None else manifest.policy.host
    port = args.port if args.port is not None else manifest.policy.port
    if not 0 <= port <= 65535:
        raise ManifestError(f"--port: must be 0 to 65535, got {port}")
    if not (args.expose or is_loopback(host)):
        raise ManifestError(f"--host: {host!r} is not a loopback address: other hosts could "
                            "reach the server (it has neither TLS nor a token); add --expose "
                            "to mean it")
    serve = standins.load(standins.POLICIES, "serve")
    return int(serve(cell_context(manifest), host, port))


__all__ = ["add_commands"]

