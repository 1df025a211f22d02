"""What `warden manifest keygen|sign|verify` says, in process: a refusal names the file and what
is wrong with it (never ``warden: None`` or a bare errno), a success names the key and the files
(mutants of each message survived the suite, which only checked the exit code and the prefix)."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import pytest

from kernel.signing import SignatureError, add_commands, generate_keypair, sign, verify

ROOT = Path(__file__).resolve().parents[2]
SIM_MANIFEST = ROOT / "manifests" / "sim-ur5e.toml"


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="warden")
    add_commands(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.handler(args)


def test_keygen_names_the_key_and_its_files(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    private, public = tmp_path / "s.key", tmp_path / "s.pub"
    assert _run(["manifest", "keygen", str(private), str(public)]) == 0
    manifest = tmp_path / "cell.toml"
    shutil.copyfile(SIM_MANIFEST, manifest)
    sign(manifest, private)
    ident = verify(manifest, tmp_path).key_id
    assert capsys.readouterr().out == (
        f"key {ident}: private {private} (keep it off the robot PC), public {public}\n")


def test_keygen_refusals_name_the_file(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    private = tmp_path / "s.key"
    generate_keypair(private, tmp_path / "s.pub")
    assert _run(["manifest", "keygen", str(private), str(tmp_path / "t.pub")]) == 2
    assert capsys.readouterr().err == (
        f"warden: {private}: already exists; refusing to overwrite a key\n")
    # The private key is written, the public one cannot be: the message names the public file
    # (not the private one the command was given first) and the reason in words.
    public = tmp_path / "missing" / "u.pub"
    assert _run(["manifest", "keygen", str(tmp_path / "u.key"), str(public)]) == 2
    assert capsys.readouterr().err == (
        f"warden: {public}: cannot write key: No such file or directory\n")
    assert not (tmp_path / "u.key").exists()  # no half key pair left behind


def test_sign_names_the_key_and_the_signature(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    private = tmp_path / "s.key"
    ident = generate_keypair(private, tmp_path / "s.pub")
    manifest = tmp_path / "cell.toml"
    shutil.copyfile(SIM_MANIFEST, manifest)
    assert _run(["manifest", "sign", str(manifest), "--key", str(private)]) == 0
    assert capsys.readouterr().out == (
        f"{manifest}: signed by key {ident} -> {manifest}.sig\n")
    assert _run(["manifest", "sign", str(manifest), "--key", str(tmp_path / "s.pub")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"warden: {tmp_path / 's.pub'}: ") and "None" not in err, err


def test_an_untrusted_signer_is_told_every_trusted_key(tmp_path: Path) -> None:
    trusted = tmp_path / "trusted"
    trusted.mkdir()
    ids = sorted(generate_keypair(tmp_path / f"{n}.key", trusted / f"{n}.pub") for n in "ab")
    manifest = tmp_path / "cell.toml"
    shutil.copyfile(SIM_MANIFEST, manifest)
    other = generate_keypair(tmp_path / "other.key", tmp_path / "other.pub")
    sign(manifest, tmp_path / "other.key")
    with pytest.raises(SignatureError) as caught:
        verify(manifest, trusted)
    text = str(caught.value)
    assert f"signed by key {other}, which is not a trusted key in {trusted} (trusted: " in text
    listed = text.rsplit("(trusted: ", 1)[1].removesuffix(")")
    assert sorted(listed.split(", ")) == ids
