"""`warden trial` checks everything before it asks a human: an envelope that bounds nothing, an
operator socket it cannot serve are refused before the card; the card gives every stop path
its bound in milliseconds."""

from __future__ import annotations

import socket
from pathlib import Path
from types import SimpleNamespace

import pytest

from kernel.signing import sign
from tests.cell.test_trial import (
    TEST_KEYS,
    TEST_SIGNER,
    TRIAL,
    _refused,
    _ur_trial,
    run_trial,
    trial_manifest,
)
from tests.safety.support import safety_table


@pytest.mark.parametrize(("key", "line", "says"), [
    ("workspace_lower[0]", "workspace_lower = [-100.0, -0.40, 0.00]", "beyond the arm's reach"),
    ("workspace_upper[2]", "workspace_upper = [-0.20, 0.35, 100.0]", "beyond the arm's reach"),
    ("max_wrist_force_n", "max_wrist_force_n = 151.0", "above the safety monitor's own limit"),
    ("speed_scale", "speed_scale = 1.0", "reduces nothing"),
])
def test_an_envelope_that_bounds_nothing_is_refused(tmp_path: Path, key: str, line: str,
                                                    says: str) -> None:
    """A box wider than the arm can reach, a force limit above the monitor's (150 N), the
    manifest's own speeds: refused before anything else is asked (no monitor runs here)."""
    old = next(row for row in TRIAL.splitlines() if row.startswith(line.split(" = ")[0]))
    manifest = trial_manifest(tmp_path, trial=TRIAL.replace(old, line),
                              extra=safety_table(tmp_path))
    sign(manifest, TEST_SIGNER)
    message = _refused(run_trial(manifest, tmp_path), tmp_path, f"trial.{key}", says)
    assert "stop: operator" not in message


def test_full_speed_is_an_explicit_opt_in(tmp_path: Path) -> None:
    """speed_scale = 1 with --full-speed passes the envelope's checks (and is refused later
    here only because no safety monitor runs)."""
    manifest = trial_manifest(tmp_path, trial=TRIAL.replace("speed_scale = 0.5",
                                                            "speed_scale = 1.0"),
                              extra=safety_table(tmp_path))
    sign(manifest, TEST_SIGNER)
    done = run_trial(manifest, tmp_path, "--full-speed")
    _refused(done, tmp_path, "no safety monitor answers")
    assert '"opt_in":"--full-speed"' in done.stderr and "trial at full speed" in done.stderr


def test_the_operator_socket_is_checked_before_anyone_is_asked(tmp_path: Path) -> None:
    """A socket that cannot be served is refused before the card and the prompt (and before
    the safety monitor is asked: none runs here), not after a human confirmed."""
    manifest = trial_manifest(tmp_path, extra=safety_table(tmp_path))
    sock = tmp_path / "operator.sock"
    manifest.write_text(manifest.read_text().replace(str(sock), str(tmp_path / "gone" / "op.sock")))
    sign(manifest, TEST_SIGNER)
    done = run_trial(manifest, tmp_path)
    _refused(done, tmp_path, "operator.socket", "gone is not a directory")
    assert "stop: operator" not in done.stderr  # no card: nobody was asked
    manifest = trial_manifest(tmp_path, extra=safety_table(tmp_path))
    sign(manifest, TEST_SIGNER)
    with socket.socket(socket.AF_UNIX) as served:  # another warden already serves it
        served.bind(str(sock))
        served.listen()
        done = run_trial(manifest, tmp_path)
    _refused(done, tmp_path, "operator.socket", "another warden serves it")
    assert "stop: operator" not in done.stderr


def test_the_card_gives_every_stop_path_its_bound_in_ms(tmp_path: Path) -> None:
    """The UR trial's card: the operator's stop at the next 2 ms tick, the monitor's 4 ms
    check and 200 ms heartbeat timeout, the controller's watchdog after 25 periods."""
    from kernel.app.trial import load_trial
    from kernel.app.trial_card import trial_card

    manifest = load_trial(_ur_trial(tmp_path, SimpleNamespace(host="127.0.0.1")), TEST_KEYS)
    card = trial_card(manifest, tmp_path / "operator.sock", "the monitor", tmp_path / "runs")
    rows = dict(line.split("  ", 1) for line in card.splitlines())
    stops = {name.strip(): text.strip() for name, text in rows.items()}
    assert "within 2 ms of the command's arrival" in stops["stop: operator"], stops
    assert ("within 4 ms of a limit crossed, 204 ms of warden's last heartbeat"
            in stops["stop: safety monitor"]), stops
    assert "watchdog: no setpoint for 25 control periods" in stops["stop: the device"]
    assert stops["stop: the device"].endswith("50 ms after warden's last command"), stops
    assert "within 2 ms" in stops["wrist force"] and "within 2 ms" in stops["tool workspace"]
