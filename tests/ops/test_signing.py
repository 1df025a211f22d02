"""Manifest signatures: round trip, every refusal named, key files, and the CLI's exit codes."""

from __future__ import annotations

import argparse
import base64
import shutil
import stat
import subprocess
from pathlib import Path

import pytest
from cryptography.hazmat.primitives import serialization

from kernel.signing import (
    SignatureError,
    add_commands,
    generate_keypair,
    key_id,
    load_private_key,
    load_public_key,
    sign,
    signature_path,
    verify,
)

ROOT = Path(__file__).resolve().parents[2]
SIM_MANIFEST = ROOT / "manifests" / "sim-ur5e.toml"
TEST_KEYS = ROOT / "manifests" / "keys" / "test-only"


@pytest.fixture
def signer(tmp_path: Path) -> tuple[Path, Path, str]:
    """A fresh key pair: (private key, trusted keys directory, key id)."""
    keys = tmp_path / "trusted"
    keys.mkdir()
    ident = generate_keypair(tmp_path / "signer.key", keys / "signer.pub")
    return tmp_path / "signer.key", keys, ident


@pytest.fixture
def manifest(tmp_path: Path) -> Path:
    path = tmp_path / "cell.toml"
    shutil.copyfile(SIM_MANIFEST, path)
    return path


def test_round_trip(manifest: Path, signer: tuple[Path, Path, str]) -> None:
    private, keys, ident = signer
    written = sign(manifest, private)
    assert written == signature_path(manifest) == manifest.with_name("cell.toml.sig")
    first_line = written.read_text().splitlines()[0]
    assert len(base64.b64decode(first_line, validate=True)) == 64
    verified = verify(manifest, keys)
    assert verified.key_id == ident and len(ident) == 16
    assert verified.key_path == keys / "signer.pub"
    assert verified.content == manifest.read_bytes()


def test_one_changed_byte_is_refused(manifest: Path, signer: tuple[Path, Path, str]) -> None:
    private, keys, ident = signer
    sign(manifest, private)
    manifest.write_bytes(manifest.read_bytes().replace(b"cycles = 3", b"cycles = 4"))
    with pytest.raises(SignatureError) as caught:
        verify(manifest, keys)
    assert str(caught.value).startswith(f"{manifest}: the file changed after it was signed")
    assert ident in str(caught.value)
    manifest.write_bytes(manifest.read_bytes() + b"\n")  # even whitespace counts
    with pytest.raises(SignatureError, match="changed after"):
        verify(manifest, keys)


def test_signed_by_an_untrusted_key(tmp_path: Path, manifest: Path,
                                    signer: tuple[Path, Path, str]) -> None:
    _, keys, trusted_id = signer
    other_id = generate_keypair(tmp_path / "other.key", tmp_path / "other.pub")
    sign(manifest, tmp_path / "other.key")
    with pytest.raises(SignatureError) as caught:
        verify(manifest, keys)
    text = str(caught.value)
    assert f"signed by key {other_id}, which is not a trusted key" in text
    assert trusted_id in text and text.startswith(str(manifest))


def test_the_key_hint_is_never_trusted(tmp_path: Path, manifest: Path,
                                       signer: tuple[Path, Path, str]) -> None:
    private, keys, ident = signer
    generate_keypair(tmp_path / "other.key", tmp_path / "other.pub")
    sig = sign(manifest, tmp_path / "other.key")
    # Claiming the trusted key's id does not make an untrusted signature valid...
    lines = sig.read_text().splitlines()
    sig.write_text(f"{lines[0]}\nkey-id: {ident}\n")
    with pytest.raises(SignatureError):
        verify(manifest, keys)
    # ...and a valid signature without any hint still verifies.
    sign(manifest, private)
    sig.write_text(sig.read_text().splitlines()[0] + "\n")
    assert verify(manifest, keys).key_id == ident
    manifest.write_bytes(manifest.read_bytes() + b"# edit\n")
    with pytest.raises(SignatureError, match="matches no trusted key"):
        verify(manifest, keys)


def test_missing_signature(manifest: Path, signer: tuple[Path, Path, str]) -> None:
    with pytest.raises(SignatureError) as caught:
        verify(manifest, signer[1])
    assert str(caught.value).startswith(f"{manifest}: not signed: no signature file")


@pytest.mark.parametrize("content", [
    "", "not base64 at all!!\n", base64.b64encode(b"x" * 63).decode() + "\n",
    base64.b64encode(b"x" * 65).decode(), "\n" + base64.b64encode(b"x" * 64).decode(),
])
def test_malformed_signature(manifest: Path, signer: tuple[Path, Path, str],
                             content: str) -> None:
    signature_path(manifest).write_text(content)
    with pytest.raises(SignatureError) as caught:
        verify(manifest, signer[1])
    assert str(caught.value).startswith(f"{manifest}: malformed signature file")


def test_binary_garbage_signature(manifest: Path, signer: tuple[Path, Path, str]) -> None:
    signature_path(manifest).write_bytes(bytes(range(256)))
    with pytest.raises(SignatureError, match="malformed signature"):
        verify(manifest, signer[1])


def test_keygen_files_and_permissions(tmp_path: Path) -> None:
    ident = generate_keypair(tmp_path / "a.key", tmp_path / "a.pub")
    assert stat.S_IMODE((tmp_path / "a.key").stat().st_mode) == 0o600
    assert stat.S_IMODE((tmp_path / "a.pub").stat().st_mode) == 0o644
    assert key_id(load_private_key(tmp_path / "a.key").public_key()) == ident
    assert key_id(load_public_key(tmp_path / "a.pub")) == ident
    before = (tmp_path / "a.key").read_bytes()
    with pytest.raises(FileExistsError, match="refusing to overwrite"):
        generate_keypair(tmp_path / "a.key", tmp_path / "b.pub")
    with pytest.raises(FileExistsError):
        generate_keypair(tmp_path / "b.key", tmp_path / "a.pub")
    assert (tmp_path / "a.key").read_bytes() == before
    assert not (tmp_path / "b.key").exists() and not (tmp_path / "b.pub").exists()


def test_raw_base64_public_keys_are_trusted(tmp_path: Path, manifest: Path) -> None:
    generate_keypair(tmp_path / "a.key", tmp_path / "a.pem")
    raw = load_public_key(tmp_path / "a.pem").public_bytes(serialization.Encoding.Raw,
                                                            serialization.PublicFormat.Raw)
    keys = tmp_path / "keys"
    keys.mkdir()
    (keys / "a.pub").write_text(base64.b64encode(raw).decode() + "\n")
    sign(manifest, tmp_path / "a.key")
    assert verify(manifest, keys).key_id == key_id(load_public_key(tmp_path / "a.pem"))


def test_broken_or_empty_trust_store(tmp_path: Path, manifest: Path,
                                     signer: tuple[Path, Path, str]) -> None:
    private, keys, _ = signer
    sign(manifest, private)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(SignatureError, match="no trusted keys") as caught:
        verify(manifest, empty)
    assert str(caught.value).startswith(f"{manifest}: cannot check the signature: ")
    with pytest.raises(SignatureError, match="no such keys directory"):
        verify(manifest, tmp_path / "nowhere")
    (keys / "broken.pub").write_text("hello\n")
    with pytest.raises(SignatureError, match=r"broken\.pub: neither a PEM public key"):
        verify(manifest, keys)
    (keys / "broken.pub").write_bytes(private.read_bytes())  # a private key is no public key
    with pytest.raises(SignatureError, match=r"broken\.pub"):
        verify(manifest, keys)


def test_the_checked_in_test_key_pair_works(manifest: Path) -> None:
    sign(manifest, TEST_KEYS / "test-signer.key")
    assert verify(manifest, TEST_KEYS).key_id == "276bb30aa3b714e0"
    # The parent directory holds no *.pub on purpose: it never trusts the test key by accident.
    with pytest.raises(SignatureError, match="no trusted keys"):
        verify(manifest, TEST_KEYS.parent)


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl not installed")
def test_openssl_accepts_our_signature(tmp_path: Path, manifest: Path,
                                       signer: tuple[Path, Path, str]) -> None:
    private, keys, _ = signer
    sig = sign(manifest, private)
    raw = tmp_path / "sig.bin"
    raw.write_bytes(base64.b64decode(sig.read_text().splitlines()[0]))
    command = ["openssl", "pkeyutl", "-verify", "-pubin", "-inkey", str(keys / "signer.pub"),
               "-rawin", "-in", str(manifest), "-sigfile", str(raw)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=30, check=False)
    if "rawin" in done.stderr and done.returncode != 0:
        pytest.skip("this openssl cannot verify Ed25519 (needs OpenSSL 3)")
    assert done.returncode == 0, done.stderr
    manifest.write_bytes(manifest.read_bytes() + b" ")
    assert subprocess.run(command, capture_output=True, timeout=30, check=False).returncode != 0


# -- the command line ---------------------------------------------------------------------------


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="warden")
    add_commands(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.handler(args)


def test_cli_keygen_sign_verify(tmp_path: Path, manifest: Path,
                                capsys: pytest.CaptureFixture[str]) -> None:
    keys = tmp_path / "keys"
    keys.mkdir()
    assert _run(["manifest", "keygen", str(tmp_path / "s.key"), str(keys / "s.pub")]) == 0
    assert _run(["manifest", "sign", str(manifest), "--key", str(tmp_path / "s.key")]) == 0
    assert _run(["manifest", "verify", str(manifest), "--keys", str(keys)]) == 0
    out = capsys.readouterr()
    assert "valid signature by trusted key" in out.out and out.err == ""


def test_cli_refusals_are_one_line_exit_2(tmp_path: Path, manifest: Path,
                                          signer: tuple[Path, Path, str],
                                          capsys: pytest.CaptureFixture[str]) -> None:
    private, keys, _ = signer
    cases = [
        ["manifest", "verify", str(manifest), "--keys", str(keys)],  # unsigned
        ["manifest", "keygen", str(private), str(tmp_path / "x.pub")],  # exists
        ["manifest", "sign", str(manifest), "--key", str(tmp_path / "nope.key")],
        ["manifest", "sign", str(manifest), "--key", str(keys / "signer.pub")],
        ["manifest", "sign", str(tmp_path / "missing.toml"), "--key", str(private)],
    ]
    for argv in cases:
        assert _run(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("warden: ") and err.count("\n") == 1, err
        assert "Traceback" not in err
    sign(manifest, private)
    manifest.write_bytes(manifest.read_bytes() + b"\n")
    assert _run(["manifest", "verify", str(manifest), "--keys", str(keys)]) == 2
    assert "changed after it was signed" in capsys.readouterr().err


def test_cli_refuses_to_sign_an_invalid_manifest(tmp_path: Path, manifest: Path,
                                                 signer: tuple[Path, Path, str],
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    manifest.write_text(manifest.read_text().replace("cycles = 3", "cylces = 3"))
    assert _run(["manifest", "sign", str(manifest), "--key", str(signer[0])]) == 2
    assert "cell.cylces: unknown key" in capsys.readouterr().err
    assert not signature_path(manifest).exists()
