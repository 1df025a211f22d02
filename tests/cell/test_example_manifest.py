"""The shipped real-device example, ``manifests/ur5e-real.example.toml``, as an integrator first
uses it: a copy with ``driver.host`` set to the controller's address (here the UR controller
emulator's, a separate process on its real transport), signed, then ``warden check`` with the
policy server it names running. It must
be accepted as it ships (every other key untouched) and must never move the arm."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from kernel.cli import main
from kernel.manifest import load_manifest
from kernel.model_file import BUILTIN
from kernel.robot_model import digest
from kernel.signing import sign
from stubs.process import EmulatorProcess
from tests.cell.harness import MANIFESTS
from tests.cell.test_check import DRIVER_ROWS, SECONDS, device, rows

pytestmark = pytest.mark.slow

EXAMPLE = MANIFESTS / "ur5e-real.example.toml"
TEST_KEYS = MANIFESTS / "keys" / "test-only"
HOST_LINE = re.compile(r'^host = "[^"]*"', re.MULTILINE)


def installed_copy(tmp: Path, host: str) -> Path:
    """The example with only ``driver.host`` replaced (its one ``host =`` line before
    ``[policy]``), signed with the repository's test-only key, as docs/operations.md says."""
    text = EXAMPLE.read_text()
    driver = text.index("[driver]")
    end = text.index("\n[", driver + 1)
    table, count = HOST_LINE.subn(f'host = "{host}"', text[driver:end])
    assert count == 1, "the example's [driver] table has no single host line"
    path = tmp / "cell.toml"
    path.write_text(text[:driver] + table + text[end:])
    sign(path, TEST_KEYS / "test-signer.key")
    return path


def test_the_example_is_a_real_device_manifest_with_everything_a_trial_needs() -> None:
    manifest = load_manifest(EXAMPLE)
    assert manifest.driver_name == "ur_rtde" and not manifest.emulator.launch
    assert not manifest.cell.simulated_operator and not manifest.policy.launch
    assert manifest.operator.socket and manifest.safety is not None
    assert manifest.safety.max_wrist_force_n is not None
    assert manifest.trial is not None
    assert manifest.driver_settings.watchdog_periods > 0  # the controller's watchdog on
    assert manifest.sections.table("timing")["state_timeout_ms"] > 0  # warden's state watchdog
    assert manifest.sections.table("robot")["model_sha256"] == digest(BUILTIN["ur5e"].path)


def test_warden_check_accepts_the_example_against_the_emulator(tmp_path: Path) -> None:
    """The policy server the example names (127.0.0.1:8765) is running, as it says it must
    be: check reaches it (a READY ``policy server`` row) without a session."""
    policy = load_manifest(EXAMPLE).policy
    with device("ur_rtde") as emulated, EmulatorProcess(
            "stubs.policy_server", "--host", policy.host, "--port", str(policy.port)):
        path = installed_copy(tmp_path, emulated.settings["host"])
        out = tmp_path / "check.json"
        code = main(["check", str(path), "--keys", str(TEST_KEYS), "--seconds", SECONDS,
                     "--json", str(out)])
        report = json.loads(out.read_text())
        assert rows(report, "NOT READY") == {}
        assert code == 0
        ready = rows(report, "READY")
        for name in ("manifest signature", "device: connect", "device: activate",
                     "state samples", "at rest while held", "device: close", "policy server",
                     *DRIVER_ROWS["ur_rtde"]):
            assert name in ready, f"{name!r} missing: {sorted(ready)}"
        assert emulated.motion_commands() == 0
