"""``warden trial MANIFEST``: a bounded trial (kernel/app/trial.py says what that takes).

Every check that can refuse the trial runs before the card is shown and a human is asked:
the signature and the envelope (and the envelope against the arm's reach and the monitor's
limits), the checks of ``warden run``, the journal directory, the operator socket, the live
safety monitor. A confirmation is never followed by "cannot start" for anything checked here.

Exit codes: 0 every planned cycle ran and verified inside the envelope; 1 the trial ended
early (a bound: the envelope, its duration, the safety monitor gone; a signal; the run's time
budget) or a cycle did not verify, the unfinished cycle counted; 2 it did not start: a
signature that does not verify, no envelope or one that bounds nothing, no watchdog, no safety
monitor, no operator socket, nobody confirmed (the message names what is wrong; nothing moved).
"""

from __future__ import annotations

import argparse
import asyncio
import grp
import os
import sys
from pathlib import Path
from typing import Any

import structlog

from kernel.app.trial import (
    TrialBound,
    check_device_settings,
    cycle_count,
    load_trial,
    safety_watching,
    verdict,
)
from kernel.app.trial_card import trial_card
from kernel.app.trial_socket import trial_socket
from kernel.cli_run import (
    EXIT_RECORD_FAILED,
    configure_logging,
    journal_directory,
    output,
    preflight,
    report_record_failure,
    run_wall,
)
from kernel.manifest import Manifest, ManifestError
from kernel.shell.device_lock import holding
from kernel.shell.operator import await_confirmation
from kernel.signing import DEFAULT_KEYS_DIR

log = structlog.get_logger("warden.trial")


def add_commands(commands: Any) -> None:
    trial = commands.add_parser(
        "trial", help="a bounded trial from a signed manifest, after a human confirms",
        description="Verify the manifest's signature, check its trial envelope and the safety "
                    "monitor, show the trial card, wait for a human to confirm, then run the "
                    "cell inside the envelope.")
    trial.add_argument("manifest")
    trial.add_argument("--keys", default=str(DEFAULT_KEYS_DIR),
                       help=f"trusted public keys (default {DEFAULT_KEYS_DIR})")
    trial.add_argument("--journal-dir", help="where run directories go (default: the manifest's)")
    trial.add_argument("--confirm-timeout", type=float, default=300.0,
                       help="seconds to wait for `warden operator confirm` (no terminal)")
    trial.add_argument("--full-speed", action="store_true",
                       help="accept speed_scale = 1 (the manifest's own velocity limits, not "
                            "reduced); logged, and on the card and in the summary")
    trial.add_argument("--json", dest="json_out", metavar="FILE",
                       help="also write the summary as JSON to FILE ('-' for stdout)")
    trial.add_argument("--log-format", choices=("auto", "json", "console"), default="auto")
    trial.add_argument("--log-level", default="INFO")
    trial.set_defaults(handler=trial_command)


def trial_command(args: argparse.Namespace) -> int:
    structured = configure_logging(args)
    if not 0 < args.confirm_timeout <= 86_400:
        raise ManifestError("--confirm-timeout: must be more than 0 and at most a day")
    manifest = load_trial(Path(args.manifest), Path(args.keys), args.full_speed)
    preflight(manifest)
    check_device_settings(manifest)
    journal = journal_directory(manifest, args.journal_dir)
    # One warden per device, taken before the card asks anyone to confirm a trial that could
    # not start anyway.
    with holding(manifest, "warden trial"):
        return _trial(manifest, journal, args, structured)


def _trial(manifest: Manifest, journal: Path | None, args: argparse.Namespace,
           structured: bool) -> int:
    with trial_socket(manifest) as (manifest, socket):
        safety = safety_watching(manifest)  # last: the monitor's answer is the freshest
        print(trial_card(manifest, socket, safety, journal), file=sys.stderr)
        confirmed_by = _confirmed(manifest, socket, args.confirm_timeout)
        bound = TrialBound(manifest.trial.max_duration_s if manifest.trial else 0.0)
        summary = run_wall(manifest, journal, bound, structured=structured)
    code, why = verdict(summary, bound, manifest.cell.cycles)
    summary["trial"] = {"ended": why, "cycles": cycle_count(summary, manifest.cell.cycles),
                        "signer": manifest.signer, "digest": manifest.digest,
                        "confirmed_by_uid": confirmed_by, "full_speed": args.full_speed,
                        "operator_socket": str(socket)}
    output(summary, args.json_out, structured)
    print(f"warden: trial {manifest.name}: {why}", file=sys.stderr)
    return EXIT_RECORD_FAILED if report_record_failure(summary) else code


def _confirmed(manifest: Manifest, socket: Path, timeout_s: float) -> int:
    """A human says go: typing the run's name at the terminal, or `warden operator confirm`;
    the uid of who confirmed (the kernel's, SO_PEERCRED, for the socket).

    Raises:
        ManifestError: nobody confirmed (the trial does not start; nothing moved).
    """
    if sys.stdin.isatty():
        # The prompt goes where the card went (stderr): stdout may carry the JSON summary
        # (--json -) or be redirected, and a prompt there is one the human never sees.
        print(f"type {manifest.name} to start the trial (anything else cancels): ", end="",
              file=sys.stderr, flush=True)
        try:
            typed = sys.stdin.readline()  # "" at end of input (Ctrl-D): not confirmed
        except KeyboardInterrupt:  # Ctrl-C at the prompt: not confirmed, not a traceback
            typed = ""
        if typed.strip() != manifest.name:
            raise ManifestError(f"{manifest.path}: trial: not confirmed at the terminal")
        log.info("trial confirmed", run=manifest.name, uid=os.getuid(), via="terminal")
        return os.getuid()
    group = manifest.operator.group or grp.getgrgid(os.getegid()).gr_name
    print(f"waiting {timeout_s:g} s for `warden operator confirm --socket {socket}`",
          file=sys.stderr)
    try:
        caller = asyncio.run(await_confirmation(socket, group, manifest.name, timeout_s))
    except KeyboardInterrupt:  # Ctrl-C while waiting: not confirmed, not a traceback
        raise ManifestError(f"{manifest.path}: trial: not confirmed (interrupted while "
                            "waiting)") from None
    except TimeoutError:
        raise ManifestError(f"{manifest.path}: trial: nobody confirmed within {timeout_s:g} s "
                            f"(warden operator confirm --socket {socket})") from None
    except (OSError, KeyError) as error:
        raise ManifestError(f"{manifest.path}: operator.socket: cannot wait for a confirmation "
                            f"at {socket}: {error}") from None
    return caller.uid
