"""Ed25519 signatures for deployment manifests: ``warden manifest keygen|sign|verify``.

A manifest ``cell.toml`` is signed by a detached file ``cell.toml.sig`` next to it. Its first
line is the base64 of the raw 64-byte Ed25519 signature over the manifest's exact bytes (no
normalisation: a changed space is a changed manifest). An optional second line
``key-id: <id>`` names the signing key; it is a hint for error messages only, never trusted:
verification tries every trusted key whatever the hint says.

Trusted keys are the ``*.pub`` files of a keys directory, each a PEM public key or the base64
of the raw 32-byte key. A key id is the first 16 hex digits of the SHA-256 of the raw key.
The private key never needs to be on the robot PC: sign on the workstation where the manifest
is reviewed, deploy the manifest, its ``.sig`` and the public key.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import os
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cryptography.exceptions import InvalidSignature, UnsupportedAlgorithm
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

SIGNATURE_SUFFIX = ".sig"
PUBLIC_KEY_SUFFIX = ".pub"
KEY_ID_HEX_CHARS = 16
SIGNATURE_BYTES = 64
RAW_KEY_BYTES = 32
DEFAULT_KEYS_DIR = Path("/etc/warden/keys")
EXIT_OK, EXIT_INVALID = 0, 2
_HINT = "key-id:"


class SignatureError(ValueError):
    """A manifest that is not validly signed; the message names the manifest and the problem."""


class Unsigned(SignatureError):
    """The manifest has no signature file at all (as opposed to one that does not verify)."""


@dataclass(frozen=True, slots=True)
class Verified:
    key_id: str
    key_path: Path
    content: bytes = field(repr=False)
    """The exact bytes the signature covers: parse these, not a second read of the file."""


@dataclass(frozen=True, slots=True)
class TrustedKey:
    key_id: str
    path: Path
    key: Ed25519PublicKey = field(repr=False)


def signature_path(manifest_path: str | Path) -> Path:
    path = Path(manifest_path)
    return path.with_name(path.name + SIGNATURE_SUFFIX)


def key_id(public_key: Ed25519PublicKey) -> str:
    raw = public_key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return hashlib.sha256(raw).hexdigest()[:KEY_ID_HEX_CHARS]


# -- keys ---------------------------------------------------------------------------------------


def generate_keypair(private_path: str | Path, public_path: str | Path) -> str:
    """Write a new private key (PEM PKCS#8, mode 0600) and its public key (PEM, 0644).

    Refuses to overwrite either file: replacing a key by accident orphans every signature made
    with it. Returns the key id.
    """
    private_path, public_path = Path(private_path), Path(public_path)
    for path in (private_path, public_path):
        if path.exists():
            raise FileExistsError(f"{path}: already exists; refusing to overwrite a key")
    key = Ed25519PrivateKey.generate()
    private_pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                    serialization.NoEncryption())
    public_pem = key.public_key().public_bytes(serialization.Encoding.PEM,
                                               serialization.PublicFormat.SubjectPublicKeyInfo)
    _write_new(private_path, private_pem, 0o600)
    try:
        _write_new(public_path, public_pem, 0o644)
    except OSError:
        private_path.unlink()  # half a key pair is worse than none
        raise
    return key_id(key.public_key())


def load_private_key(path: str | Path) -> Ed25519PrivateKey:
    path = Path(path)
    data = _read(path, "private key")
    try:
        key = serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError, UnsupportedAlgorithm) as error:
        raise SignatureError(f"{path}: not an unencrypted PEM private key "
                             f"({type(error).__name__})") from error
    if not isinstance(key, Ed25519PrivateKey):
        raise SignatureError(f"{path}: not an Ed25519 private key")
    return key


def load_public_key(path: str | Path) -> Ed25519PublicKey:
    """A PEM public key, or the base64 of the raw 32-byte key."""
    path = Path(path)
    data = _read(path, "public key")
    if data.lstrip().startswith(b"-----BEGIN"):
        try:
            key = serialization.load_pem_public_key(data)
        except (ValueError, UnsupportedAlgorithm) as error:
            raise SignatureError(f"{path}: not a valid PEM public key") from error
        if not isinstance(key, Ed25519PublicKey):
            raise SignatureError(f"{path}: not an Ed25519 public key")
        return key
    raw = _base64(data, RAW_KEY_BYTES)
    if raw is None:
        raise SignatureError(f"{path}: neither a PEM public key nor the base64 of a raw "
                             f"{RAW_KEY_BYTES}-byte Ed25519 key")
    return Ed25519PublicKey.from_public_bytes(raw)


def trusted_keys(keys_dir: str | Path) -> list[TrustedKey]:
    """Every ``*.pub`` key of ``keys_dir``; a broken key file is an error, not skipped."""
    keys_dir = Path(keys_dir)
    if not keys_dir.is_dir():
        raise SignatureError(f"{keys_dir}: no such keys directory")
    keys = []
    for path in sorted(keys_dir.glob(f"*{PUBLIC_KEY_SUFFIX}")):
        public = load_public_key(path)
        keys.append(TrustedKey(key_id(public), path, public))
    if not keys:
        raise SignatureError(f"{keys_dir}: no trusted keys (*{PUBLIC_KEY_SUFFIX} files)")
    return keys


# -- sign and verify ----------------------------------------------------------------------------


def sign(manifest_path: str | Path, private_key_path: str | Path) -> Path:
    """Sign the manifest's exact bytes; write and return ``<manifest>.sig``."""
    manifest_path = Path(manifest_path)
    key = load_private_key(private_key_path)
    content = _read(manifest_path, "manifest")
    signature = base64.b64encode(key.sign(content)).decode()
    target = signature_path(manifest_path)
    _write_replace(target, f"{signature}\n{_HINT} {key_id(key.public_key())}\n".encode())
    return target


def verify(manifest_path: str | Path, keys_dir: str | Path) -> Verified:
    """Check the manifest against its ``.sig`` and the trusted keys, or raise SignatureError."""
    manifest_path = Path(manifest_path)
    content = _read(manifest_path, "manifest")
    signature, hint = _read_signature(manifest_path)
    try:
        keys = trusted_keys(keys_dir)
    except SignatureError as error:
        raise SignatureError(f"{manifest_path}: cannot check the signature: {error}") from error
    for trusted in keys:
        try:
            trusted.key.verify(signature, content)
        except InvalidSignature:
            continue
        return Verified(trusted.key_id, trusted.path, content)
    raise SignatureError(_mismatch(manifest_path, hint, keys, Path(keys_dir)))


def _read_signature(manifest_path: Path) -> tuple[bytes, str | None]:
    path = signature_path(manifest_path)
    if not path.exists():
        raise Unsigned(f"{manifest_path}: not signed: no signature file {path} "
                             f"(sign it with `warden manifest sign`)")
    lines = _read(path, "signature").decode("ascii", errors="replace").splitlines()
    signature = _base64(lines[0].encode() if lines else b"", SIGNATURE_BYTES)
    if signature is None:
        raise SignatureError(f"{manifest_path}: malformed signature file {path}: the first line "
                             f"must be the base64 of a {SIGNATURE_BYTES}-byte Ed25519 signature")
    hints = [line[len(_HINT):].strip() for line in lines[1:] if line.startswith(_HINT)]
    return signature, hints[0] if hints else None


def _mismatch(manifest_path: Path, hint: str | None, keys: list[TrustedKey],
              keys_dir: Path) -> str:
    known = ", ".join(k.key_id for k in keys)
    if hint is not None and hint in {k.key_id for k in keys}:
        return (f"{manifest_path}: the file changed after it was signed: the signature by "
                f"trusted key {hint} does not match its bytes")
    if hint is not None:
        return (f"{manifest_path}: signed by key {hint}, which is not a trusted key in "
                f"{keys_dir} (trusted: {known})")
    return (f"{manifest_path}: the signature matches no trusted key in {keys_dir} (trusted: "
            f"{known}): signed by another key, or the file changed after signing")


# -- files --------------------------------------------------------------------------------------


def _read(path: Path, what: str) -> bytes:
    try:
        return path.read_bytes()
    except OSError as error:
        raise SignatureError(f"{path}: cannot read {what}: {error.strerror or error}") from error


def _base64(data: bytes, length: int) -> bytes | None:
    try:
        raw = base64.b64decode(data.strip(), validate=True)
    except (binascii.Error, ValueError):
        return None
    return raw if len(raw) == length else None


def _write_new(path: Path, data: bytes, mode: int) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, mode)
    try:
        os.fchmod(fd, mode)  # the umask must not decide who can read a private key
        os.write(fd, data)
    finally:
        os.close(fd)


def _write_replace(path: Path, data: bytes) -> None:
    """Write a sibling temp file and rename it: a reader never sees half a signature."""
    fd, temp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as out:
            os.fchmod(out.fileno(), 0o644)
            out.write(data)
        os.replace(temp, path)
    except BaseException:
        Path(temp).unlink(missing_ok=True)
        raise


# -- command line -------------------------------------------------------------------------------


def add_commands(commands: Any) -> None:
    """Register ``manifest keygen|sign|verify`` on the ``warden`` subparsers object."""
    manifest = commands.add_parser(
        "manifest", help="sign and verify deployment manifests (Ed25519)",
        description="Detached Ed25519 signatures: MANIFEST.sig next to MANIFEST.")
    sub = manifest.add_subparsers(dest="manifest_command", required=True)
    keygen = sub.add_parser("keygen", help="create a signing key pair",
                            description="Write a new private key (0600) and its public key.")
    keygen.add_argument("private_key", help="where to write the private key (PEM)")
    keygen.add_argument("public_key", help="where to write the public key (PEM, *.pub)")
    keygen.set_defaults(handler=_keygen_command)
    signer = sub.add_parser("sign", help="sign a manifest (writes MANIFEST.sig)",
                            description="Check that MANIFEST loads, then sign its exact bytes.")
    signer.add_argument("manifest", help="deployment manifest (TOML)")
    signer.add_argument("--key", required=True, help="private key (PEM)")
    signer.set_defaults(handler=_sign_command)
    check = sub.add_parser("verify", help="verify a manifest's signature",
                           description="Exit 0 if MANIFEST.sig is a valid signature of MANIFEST "
                                       "by a key in the keys directory, else exit 2.")
    check.add_argument("manifest", help="deployment manifest (TOML)")
    check.add_argument("--keys", default=str(DEFAULT_KEYS_DIR),
                       help=f"directory of trusted *.pub keys (default: {DEFAULT_KEYS_DIR})")
    check.set_defaults(handler=_verify_command)


def _keygen_command(args: Any) -> int:
    try:
        ident = generate_keypair(args.private_key, args.public_key)
    except FileExistsError as error:
        return _fail(str(error))
    except OSError as error:
        return _fail(f"{error.filename or args.private_key}: cannot write key: "
                     f"{error.strerror or error}")
    print(f"key {ident}: private {args.private_key} (keep it off the robot PC), "
          f"public {args.public_key}")
    return EXIT_OK


def _sign_command(args: Any) -> int:
    from kernel.manifest import load_manifest
    from kernel.scenario.fields import ScenarioError

    try:
        # Never sign a file the runtime would refuse; the policy link's CA bundle, key and
        # token live on the robot PC, not where manifests are signed.
        load_manifest(args.manifest, credentials=False)
        ident = key_id(load_private_key(args.key).public_key())
        target = sign(args.manifest, args.key)
    except (ScenarioError, SignatureError) as error:
        return _fail(str(error))
    except OSError as error:
        return _fail(f"{error.filename or args.manifest}: cannot write signature: "
                     f"{error.strerror or error}")
    print(f"{args.manifest}: signed by key {ident} -> {target}")
    return EXIT_OK


def _verify_command(args: Any) -> int:
    try:
        verified = verify(args.manifest, args.keys)
    except SignatureError as error:
        return _fail(str(error))
    print(f"{args.manifest}: valid signature by trusted key {verified.key_id} "
          f"({verified.key_path})")
    return EXIT_OK


def _fail(text: str) -> int:
    print(f"warden: {text}", file=sys.stderr)
    return EXIT_INVALID


__all__ = ["SignatureError", "TrustedKey", "Unsigned", "Verified", "add_commands",
           "generate_keypair",
           "key_id", "load_private_key", "load_public_key", "sign", "signature_path",
           "trusted_keys", "verify"]
