"""``warden run --keys DIR``: the service's run verifies the manifest's signature itself, on the
very bytes it then parses (the unit's ``ExecStartPre`` check alone leaves a window in which the
file can change before ``warden run`` reads it again)."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest

from kernel import signing
from kernel.cli import main
from kernel.signing import sign
from tests.cell.harness import MANIFESTS

TEST_KEYS = MANIFESTS / "keys" / "test-only"
TEST_SIGNER = TEST_KEYS / "test-signer.key"


@pytest.fixture
def signed(tmp_path: Path) -> Path:
    manifest = tmp_path / "cell.toml"
    shutil.copyfile(MANIFESTS / "sim-ur5e.toml", manifest)
    sign(manifest, TEST_SIGNER)
    return manifest


def _run(manifest: Path, tmp_path: Path) -> int:
    return main(["run", str(manifest), "--keys", str(TEST_KEYS), "--clock", "virtual",
                 "--cycles", "1", "--journal-dir", str(tmp_path / "runs")])


def _header(tmp_path: Path) -> dict:
    (journal,) = (tmp_path / "runs").glob("*/journal.jsonl")
    return json.loads(journal.open().readline())


def test_a_signed_manifest_runs_and_its_journal_names_the_signer(
        signed: Path, tmp_path: Path) -> None:
    assert _run(signed, tmp_path) == 0
    provenance = _header(tmp_path)["provenance"]
    assert provenance["signer"] == signing.verify(signed, TEST_KEYS).key_id
    assert provenance["manifest"]["sha256"] == hashlib.sha256(signed.read_bytes()).hexdigest()


@pytest.mark.parametrize("damage", ["unsigned", "altered"])
def test_an_unsigned_or_altered_manifest_exits_2_before_anything_starts(
        signed: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: str) -> None:
    if damage == "unsigned":
        signing.signature_path(signed).unlink()
    else:
        signed.write_text(signed.read_text().replace("cycles = 3", "cycles = 4", 1))
    assert _run(signed, tmp_path) == 2
    err = capsys.readouterr().err
    assert str(signed) in err and f"--keys {TEST_KEYS}" in err and "Traceback" not in err
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_the_bytes_that_run_are_the_bytes_verified(signed: Path, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """The file is replaced the instant its signature has verified: the run still parses the
    verified bytes, and its journal names their digest."""
    verified_bytes = signed.read_bytes()
    verify = signing.verify

    def verify_then_swap(path: Path, keys: Path) -> signing.Verified:
        verified = verify(path, keys)
        Path(path).write_text(Path(path).read_text().replace("cycles = 3", "cycles = 1000", 1))
        return verified

    monkeypatch.setattr(signing, "verify", verify_then_swap)
    assert _run(signed, tmp_path) == 0
    header = _header(tmp_path)
    assert header["provenance"]["manifest"]["sha256"] == hashlib.sha256(
        verified_bytes).hexdigest()
    assert signed.read_bytes() != verified_bytes  # the swap did happen
