"""The ``warden`` command line.

    warden replay SCENARIO|JOURNAL [--out FILE] [--pretty] [--check]
    warden run [MANIFEST] [--cycles N] [--clock wall|virtual] [--json FILE]
    warden check MANIFEST [--seconds S] [--keys DIR] [--json FILE]
    warden serve-policy [MANIFEST] [--host HOST] [--port N] [--expose]
    warden manifest keygen|sign|verify ...

Exit codes: 0 the command ran (a refused chunk is a result, not an error); 1 ``--check`` found
a broken expectation, or a run journal did not replay bit for bit (its first difference is
named), or ``warden check`` found a check NOT READY; 2 invalid input (the message names the
file, the place and the field); 3 the record is incomplete: ``warden run`` could not write its
journal (the core stopped the arm and the run ended), or ``warden replay`` found a journal or
decision log that ends early (a last line cut off, or a decision log that stops before the
replay does); everything both files hold was replayed, compared and identical; 130 / 143
``warden run`` was ended by SIGINT / SIGTERM, in order (the arm held, the journal closed:
:mod:`kernel.app.interrupt`).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import msgspec

from drivers.base import DriverError
from kernel import signing
from kernel.app.interrupt import EXIT_INTERRUPTED
from kernel.cli_check import add_commands as add_check_commands
from kernel.cli_operator import add_commands as add_operator_commands
from kernel.cli_run import add_commands
from kernel.cli_safety import add_commands as add_safety_commands
from kernel.cli_trial import add_commands as add_trial_commands
from kernel.core.lines import encode
from kernel.replay import Replay, as_dict, check_expectations
from kernel.scenario.load import Scenario, ScenarioError, load_scenario
from kernel.timeline import render

EXIT_OK, EXIT_CHECK_FAILED, EXIT_INVALID, EXIT_INCOMPLETE = 0, 1, 2, 3


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except ScenarioError as error:
        print(f"warden: invalid input: {error}", file=sys.stderr)
        return EXIT_INVALID
    except DriverError as error:
        print(f"warden: cannot start the device: {error}", file=sys.stderr)
        return EXIT_INVALID
    except BrokenPipeError:
        return EXIT_OK
    except KeyboardInterrupt:  # Ctrl-C outside a run (a run notes it and ends in order)
        print("warden: interrupted (SIGINT)", file=sys.stderr)
        return EXIT_INTERRUPTED["SIGINT"]


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="warden",
        description="Admit learned action chunks through identity, time, context, divergence "
                    "and feasibility gates; hand motion to the right owner.",
    )
    parser.add_argument("--version", action="version", version=_version_text(),
                        help="the installed warden's version and the git revision it runs from")
    commands = parser.add_subparsers(dest="command", required=True)
    rep = commands.add_parser(
        "replay", help="replay a scenario or run journal on a virtual clock",
        description="Print the decision log of SCENARIO as JSON lines.",
    )
    rep.add_argument("scenario", help="scenario file (JSON) or run journal (JSON lines)")
    rep.add_argument("--out", help="also write the decision log to this file")
    rep.add_argument("--pretty", action="store_true", help="print a readable timeline instead")
    rep.add_argument("--check", action="store_true",
                     help="verify the scenario's 'expect'/'forbid' matchers (exit 1 if broken)")
    rep.set_defaults(handler=_replay)
    export = commands.add_parser(
        "export", help="write a run's record in a format other tools open",
        description="Write RUN (a run directory: journal.jsonl, decisions.jsonl) as an MCAP "
                    "file that Foxglove opens (kernel/export.py says what goes in which topic).")
    export.add_argument("run", help="the run directory")
    export.add_argument("--mcap", action="store_true", required=True,
                        help="write MCAP (the one format so far)")
    export.add_argument("--out", help="the file to write (default: RUN/run.mcap); never "
                                      "overwritten")
    export.set_defaults(handler=_export)
    add_commands(commands)
    add_operator_commands(commands)
    add_trial_commands(commands)
    add_safety_commands(commands)
    add_check_commands(commands)
    signing.add_commands(commands)
    return parser


def _export(args: argparse.Namespace) -> int:
    from kernel.export import export_mcap

    run = Path(args.run)
    out = Path(args.out) if args.out else run / "run.mcap"
    counts = export_mcap(run, out)
    print(f"{out}: {sum(counts.values())} messages on {len(counts)} topics")
    for topic, count in sorted(counts.items()):
        print(f"  {topic:20} {count}")
    return EXIT_OK


def _version_text() -> str:
    """``warden 0.1.0 (revision 018d1bf...)``: the installed package's version and the commit a
    journal's header would name (kernel/provenance.py), "unknown" outside a checkout."""
    from kernel.provenance import revision, software_version

    return f"warden {software_version()} (revision {revision()})"


def _replay(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    if scenario.cut is not None:
        print(f"warden: {scenario.path}: line {scenario.cut} is incomplete (the run was cut "
              f"off while writing it): replaying lines 1 to {scenario.cut - 1}",
              file=sys.stderr)
    run = Replay(scenario)
    encoded = [encode(line) for line in run.lines()]
    if args.out:
        try:
            with open(args.out, "wb") as out:
                out.writelines(line + b"\n" for line in encoded)
        except OSError as error:
            raise ScenarioError(f"{args.out}: cannot write: {error.strerror}") from None
    decoded = [msgspec.json.decode(line) for line in encoded] if (
        args.pretty or args.check) else []
    if args.pretty:
        print(f"# {scenario.name} ({scenario.path})")
        for text in render(decoded):
            print(text)
    else:
        sys.stdout.buffer.writelines(line + b"\n" for line in encoded)
        sys.stdout.flush()
    verdict = _verify_journal(scenario, run, encoded) if scenario.recorded_ticks else EXIT_OK
    checked = _check(scenario, decoded) if args.check else EXIT_OK
    if EXIT_CHECK_FAILED in (verdict, checked):
        return EXIT_CHECK_FAILED
    return max(verdict, checked)


def _verify_journal(scenario: Scenario, run: Replay, encoded: list[bytes]) -> int:
    """A run journal replays bit for bit: every command, and the run's decision log if it sits
    beside the journal. Says so on stderr, or names the first difference (exit 1).

    A record that ends early is compared as far as it goes and said to be incomplete (exit 3):
    a last line cut off (in the journal or the decision log), or a decision log that is a
    whole-line prefix of the replay (a run killed after writing a batch to its journal and
    before writing it to its decision log).
    """
    problem = run.first_difference
    decisions = Path(scenario.path).with_name("decisions.jsonl")
    compared = decisions.is_file()
    notes: list[str] = []
    recorded: list[bytes] = []
    if problem is None and compared:
        recorded, problem = _compare_decisions(scenario, decisions, encoded, notes)
    where = f"{scenario.path}: replay"
    if problem is not None:
        print(f"warden: {where}: first difference {problem}", file=sys.stderr)
        return EXIT_CHECK_FAILED
    for note in notes:
        print(f"warden: {note}", file=sys.stderr)
    if scenario.cut is None and not notes:
        against = f" and the {len(encoded)} lines of {decisions.name}" if compared else ""
        print(f"warden: {where}: identical: {run.commands_checked} commands{against}",
              file=sys.stderr)
        return EXIT_OK
    against = (f" and the {min(len(recorded), len(encoded))} decision lines both files hold"
               if compared else "")
    print(f"warden: {where}: identical as far as the record goes: {run.commands_checked} "
          f"commands{against}; the record is incomplete", file=sys.stderr)
    return EXIT_INCOMPLETE


def _compare_decisions(scenario: Scenario, decisions: Path, encoded: list[bytes],
                       notes: list[str]) -> tuple[list[bytes], str | None]:
    """The recorded decision lines and the first difference from the replayed ones; how the
    record ends early, if it does, goes to ``notes``.

    Raises:
        ScenarioError: the decision log cannot be read.
    """
    try:
        recorded, cut = _whole_lines(decisions.read_bytes())
    except OSError as error:
        raise ScenarioError(f"{decisions}: cannot read file: {error.strerror}") from None
    problem = _first_line_difference(recorded, encoded)
    if problem is not None:
        return recorded, problem
    if cut is not None:
        notes.append(f"{decisions}: line {cut} is incomplete (the run was cut off while "
                     "writing it): compared the lines before it")
    elif len(recorded) < len(encoded):
        notes.append(f"{decisions}: ends after {len(recorded)} of the {len(encoded)} lines "
                     "replayed (the run stopped before writing the rest)")
    elif len(recorded) > len(encoded) and scenario.cut is None:
        return recorded, (f"in decisions.jsonl: {len(recorded)} lines recorded, "
                          f"{len(encoded)} replayed")
    return recorded, None


def _whole_lines(data: bytes) -> tuple[list[bytes], int | None]:
    """The complete lines of a decision log, and the number of an incomplete last one."""
    lines = data.splitlines()
    if not data or data.endswith((b"\n", b"\r")):
        return lines, None
    return lines[:-1], len(lines)


def _first_line_difference(recorded: list[bytes], replayed: list[bytes]) -> str | None:
    """The first line both hold that differs."""
    for number, (old, new) in enumerate(zip(recorded, replayed, strict=False), start=1):
        if old != new:
            # The recorded file may be damaged: never fail on its bytes while quoting them.
            return (f"in decisions.jsonl line {number}: recorded "
                    f"{old.decode(errors='replace')[:300]}, replayed {new.decode()[:300]}")
    return None


def _check(scenario, decoded) -> int:  # type: ignore[no-untyped-def]
    problems = check_expectations(scenario, decoded)
    for problem in problems:
        print(f"warden: {scenario.path}: {problem}", file=sys.stderr)
    if not scenario.expect and not scenario.forbid:
        print(f"warden: {scenario.path}: no expectations to check", file=sys.stderr)
    return EXIT_CHECK_FAILED if problems else EXIT_OK


__all__ = ["as_dict", "main"]


if __name__ == "__main__":
    sys.exit(main())
