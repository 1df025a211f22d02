"""``[policy.tls]`` and ``[policy.auth]`` in a manifest: every file and the token are read
while it loads, so a missing bundle, a key others can read or an unset variable exits 2 with
one line naming the file and the key, before anything starts; a good one is carried to the
link, and the token never shows in a repr."""

from __future__ import annotations

from pathlib import Path

import pytest

from kernel.cli import main
from kernel.manifest import load_manifest
from tests.cell.harness import MANIFESTS
from tests.cell.test_run_cli import nothing_starts
from tests.cli.test_settings_bounds_cli import _assert_refused, no_emulator_starts
from tests.wire.pki import Pki, make_pki

__all__ = ["no_emulator_starts", "nothing_starts"]  # fixtures, shared


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return make_pki(tmp_path_factory.mktemp("pki"))


def _manifest(tmp_path: Path, tables: str, launch: bool = False) -> Path:
    text = (MANIFESTS / "sim-ur5e.toml").read_text()
    if not launch:
        text = text.replace("launch = true ", "launch = false", 1).replace(
            "port = 0 ", "port = 8765", 1)
    path = tmp_path / "cell.toml"
    path.write_text(f"{text}\n{tables}\n")
    return path


def _secret(path: Path, text: str, mode: int = 0o600) -> Path:
    path.write_text(text)
    path.chmod(mode)
    return path


def _cases(tmp_path: Path, pki: Pki) -> dict[str, tuple[str, str, bool]]:
    garbage = tmp_path / "garbage.pem"
    garbage.write_text("not a certificate\n")
    loose_key = _secret(tmp_path / "loose.key", pki.client_key.read_text(), 0o644)
    loose_token = _secret(tmp_path / "loose.token", "abc\n", 0o644)
    spaced = _secret(tmp_path / "spaced.token", "two words\n")
    token = _secret(tmp_path / "good.token", "abc\n")
    tls = f'[policy.tls]\nca_file = "{pki.ca}"\n'
    return {
        "launched": (tls, "policy.tls: only with launch = false", True),
        "missing bundle": ('[policy.tls]\nca_file = "missing.pem"\n',
                           f"policy.tls.ca_file: {tmp_path / 'missing.pem'}: no such file",
                           False),
        "garbage bundle": (f'[policy.tls]\nca_file = "{garbage}"\n',
                           "policy.tls.ca_file: not a PEM certificate bundle", False),
        "cert without key": (f'{tls}cert_file = "{pki.client_cert}"\n',
                             "policy.tls.key_file: cert_file and key_file go together", False),
        "key others read": (f'{tls}cert_file = "{pki.client_cert}"\nkey_file = "{loose_key}"\n',
                            "policy.tls.key_file: " + str(loose_key) + ": readable by others "
                            "(mode 644); chmod 600 it", False),
        "unknown tls key": (f"{tls}colour = 1\n", "policy.tls.colour: unknown key", False),
        "both token places": (f'[policy.auth]\ntoken_file = "{token}"\ntoken_env = "X"\n',
                              "policy.auth: name exactly one of token_file and token_env",
                              False),
        "no token place": ("[policy.auth]\n",
                           "policy.auth: name exactly one of token_file and token_env", False),
        "unset variable": ('[policy.auth]\ntoken_env = "WARDEN_TEST_TOKEN_NEVER_SET"\n',
                           "policy.auth.token_env: the environment variable "
                           "WARDEN_TEST_TOKEN_NEVER_SET is not set or empty", False),
        "bad variable name": ('[policy.auth]\ntoken_env = "1-BAD"\n',
                              "policy.auth.token_env: must match", False),
        "token others read": (f'[policy.auth]\ntoken_file = "{loose_token}"\n',
                              "policy.auth.token_file: " + str(loose_token) + ": readable by "
                              "others", False),
        "token of two words": (f'[policy.auth]\ntoken_file = "{spaced}"\n',
                               "policy.auth.token_file: the token must be one word", False),
        "token inline": ('[policy.auth]\ntoken = "abc"\n', "policy.auth.token: unknown key",
                         False),
    }


CASES = ["launched", "missing bundle", "garbage bundle", "cert without key", "key others read",
         "unknown tls key", "both token places", "no token place", "unset variable",
         "bad variable name", "token others read", "token of two words", "token inline"]


@pytest.mark.parametrize("case", CASES)
@pytest.mark.usefixtures("nothing_starts", "no_emulator_starts")
def test_an_unusable_tls_or_token_setting_exits_2_before_anything_starts(
        tmp_path: Path, pki: Pki, capsys: pytest.CaptureFixture[str], case: str) -> None:
    tables, needle, launch = _cases(tmp_path, pki)[case]
    path = _manifest(tmp_path, tables, launch)
    runs = tmp_path / "runs"
    code = main(["run", str(path), "--journal-dir", str(runs)])
    _assert_refused(code, capsys.readouterr().err, runs, path, needle)


def test_a_usable_setting_reaches_the_link_and_hides_the_token(
        tmp_path: Path, pki: Pki, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("WARDEN_TEST_POLICY_TOKEN", "s3cret-token")
    path = _manifest(tmp_path, f'[policy.tls]\nca_file = "{pki.ca}"\ncert_file = '
                               f'"{pki.client_cert}"\nkey_file = "{pki.client_key}"\n'
                               f'server_name = "localhost"\n[policy.auth]\n'
                               f'token_env = "WARDEN_TEST_POLICY_TOKEN"\n')
    manifest = load_manifest(path)
    security = manifest.link_security
    assert security.scheme == "wss" and security.server_name == "localhost"
    assert security.tls is not None and security.token is not None
    assert security.token.reveal() == "s3cret-token"
    assert "s3cret" not in repr(manifest) and "s3cret" not in repr(security)
    assert security.headers(manifest.policy.protocol) == [
        ("Authorization", "Bearer s3cret-token")]


def test_signing_elsewhere_and_the_operator_need_no_credentials(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Manifests are signed on another machine, and ``warden operator`` runs as an operator:
    neither reads the CA bundle or the token, which live on the robot PC for the service's
    user (a run still refuses the same file, naming the key). What the tables must say is
    checked everywhere."""
    from kernel.cli_operator import _socket
    from kernel.signing import generate_keypair

    monkeypatch.delenv("WARDEN_TEST_TOKEN_NEVER_SET", raising=False)
    tables = ('[policy.tls]\nca_file = "/etc/warden/policy-ca.pem"\n'
              '[policy.auth]\ntoken_env = "WARDEN_TEST_TOKEN_NEVER_SET"\n')
    path = _manifest(tmp_path, tables + f'[operator]\nsocket = "{tmp_path / "op.sock"}"\n')
    generate_keypair(tmp_path / "signer.key", tmp_path / "signer.pub")
    assert main(["manifest", "sign", str(path), "--key", str(tmp_path / "signer.key")]) == 0
    assert _socket(str(path), "") == tmp_path / "op.sock"
    assert main(["run", str(path), "--journal-dir", str(tmp_path / "runs")]) == 2
    assert "policy.tls.ca_file: /etc/warden/policy-ca.pem: no such file" in (
        capsys.readouterr().err)
    shaped = _manifest(tmp_path, '[policy.auth]\ntoken_env = "A"\ntoken_file = "t"\n')
    assert main(["manifest", "sign", str(shaped), "--key", str(tmp_path / "signer.key")]) == 2
    assert "policy.auth: name exactly one of token_file and token_env" in (
        capsys.readouterr().err)
